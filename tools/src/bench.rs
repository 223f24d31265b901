//! `latentam bench ...`: benchmarks that print a table and write JSON.
//! Times are GPU time from timestamp queries (the sum of the operation's
//! commands), median over the measured runs after one warm-up run (lavapipe
//! compiles a pipeline on its first dispatch).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context as _, Result};
use clap::Subcommand;
use latentam_gpu::ops::{
    self, Gemm, GemmKernel, PrefixScan, RadixSorter, ReduceOp, Reducer, Transpose,
};
use latentam_gpu::{Buffer, Context, ContextOptions, Recorder};
use rand::{Rng, SeedableRng};
use serde::Serialize;

#[derive(Subcommand)]
pub enum Which {
    /// Time every GPU primitive at the sizes the mapper uses: sort of 1M and
    /// 8M keys, scan and reduction of 16M, GEMM 2000x768x2000 in the three
    /// layouts, softmax of 2000x2000, scatter-add, and a 64 MiB copy for the
    /// memory bandwidth.
    Primitives {
        /// Write the results as JSON to this file.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Measured runs per primitive (after one warm-up run); at least 5.
        #[arg(long, default_value_t = 7, value_parser = clap::value_parser!(u32).range(5..))]
        runs: u32,
        /// Sizes divided by 16, for a fast smoke run (not for reporting).
        #[arg(long)]
        quick: bool,
    },
    /// Time the rasterizer's forward and backward passes over a batch of
    /// views of a room whose walls are covered with Gaussians, with a
    /// per-kernel breakdown; count the blending work with the CPU reference
    /// and report how far the time is from the machine's measured FMA rate
    /// and copy bandwidth for that work.
    Raster {
        /// Image width in pixels.
        #[arg(long, default_value_t = 320, value_parser = clap::value_parser!(u32).range(1..=16384))]
        width: u32,
        /// Image height in pixels.
        #[arg(long, default_value_t = 240, value_parser = clap::value_parser!(u32).range(1..=16384))]
        height: u32,
        /// Number of Gaussians in the scene.
        #[arg(long, default_value_t = 100_000, value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
        gaussians: u64,
        /// Views rendered per batch.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
        views: u32,
        /// Measured runs (after one warm-up run); at least 3.
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(3..))]
        runs: u32,
        /// Write the results as JSON to this file.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Time the latent head: attention decoder forward and backward, one
    /// Stage II iteration (decode, feature loss, backward, trust region, Adam
    /// on W and D), a streaming k-means update on a full dictionary, and the
    /// image losses (L1 + SSIM + depth) on one view.
    Latent {
        /// Regions decoded at once (n).
        #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u32).range(1..=100_000))]
        regions: u32,
        /// Dictionary atoms (K).
        #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u32).range(1..=65_536))]
        atoms: u32,
        /// Embedding dimension (d_f).
        #[arg(long, default_value_t = 768, value_parser = clap::value_parser!(u32).range(1..=16_384))]
        dim: u32,
        /// Width of the image of the SSIM measurement.
        #[arg(long, default_value_t = 640, value_parser = clap::value_parser!(u32).range(1..=16384))]
        ssim_width: u32,
        /// Height of the image of the SSIM measurement.
        #[arg(long, default_value_t = 480, value_parser = clap::value_parser!(u32).range(1..=16384))]
        ssim_height: u32,
        /// Measured runs (after one warm-up run); at least 3.
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(3..))]
        runs: u32,
        /// Write the results as JSON to this file.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Time the input side on the CPU: CDR decoding, frame assembly and
    /// reading frames from an MCAP log (uncompressed, lz4, zstd), for
    /// frame sets of a colour image, 16UC1 depth and region embeddings.
    Ingest {
        /// Image width in pixels.
        #[arg(long, default_value_t = 640, value_parser = clap::value_parser!(u32).range(16..=8192))]
        width: u32,
        /// Image height in pixels.
        #[arg(long, default_value_t = 480, value_parser = clap::value_parser!(u32).range(16..=8192))]
        height: u32,
        /// Regions per frame.
        #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u32).range(1..=65_535))]
        regions: u32,
        /// Embedding dimension.
        #[arg(long, default_value_t = 768, value_parser = clap::value_parser!(u32).range(1..=16_384))]
        dim: u32,
        /// Frame sets (at least 4).
        #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u64).range(4..=100_000))]
        frames: u64,
        /// Write the results as JSON to this file.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Map a log end to end (the generated scene unless --log is given):
    /// keyframes/s, ms per keyframe by stage, paging and the share Stage II
    /// hid, peak GPU and CPU bytes, Gaussians, per-keyframe memory curves,
    /// and the PSNR of re-rendered keyframes.
    Map {
        /// Frames to map (of the generated scene, or the first N of --log).
        #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
        frames: u64,
        /// Generated scene image width.
        #[arg(long, default_value_t = 160, value_parser = clap::value_parser!(u32).range(16..=4096))]
        width: u32,
        /// Generated scene image height.
        #[arg(long, default_value_t = 120, value_parser = clap::value_parser!(u32).range(16..=4096))]
        height: u32,
        /// Generated scene embedding dimension.
        #[arg(long, default_value_t = 512, value_parser = clap::value_parser!(u64).range(1..=8192))]
        dim: u64,
        /// Map this MCAP log instead of a generated scene.
        #[arg(long)]
        log: Option<PathBuf>,
        /// Mapper configuration (TOML; unknown keys are errors).
        #[arg(long)]
        config: Option<PathBuf>,
        /// GPU memory budget in bytes (overrides the configuration).
        #[arg(long)]
        budget: Option<u64>,
        /// Keyframes re-rendered for the PSNR at the end (0: none).
        #[arg(long, default_value_t = 20)]
        eval_keyframes: u64,
        /// Write the results (with the per-keyframe curves) as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Long run on the demo scene walked lap after lap: GPU and CPU bytes,
    /// Gaussians, kept keyframes and live Vulkan objects per keyframe, and
    /// per lap.
    Soak(crate::bench_soak::Args),
}

pub fn run(which: Which) -> Result<()> {
    match which {
        Which::Primitives { json, runs, quick } => primitives(json, runs as usize, quick),
        Which::Raster {
            width,
            height,
            gaussians,
            views,
            runs,
            json,
        } => crate::bench_raster::run(crate::bench_raster::RasterBench {
            width,
            height,
            gaussians,
            views,
            runs: runs as usize,
            json,
        }),
        Which::Latent {
            regions,
            atoms,
            dim,
            ssim_width,
            ssim_height,
            runs,
            json,
        } => crate::bench_latent::run(crate::bench_latent::LatentBench {
            regions,
            atoms,
            dim,
            ssim_width,
            ssim_height,
            runs: runs as usize,
            json,
        }),
        Which::Soak(args) => crate::bench_soak::run_bench(args),
        Which::Map {
            frames,
            width,
            height,
            dim,
            log,
            config,
            budget,
            eval_keyframes,
            json,
        } => crate::bench_map::run(crate::bench_map::MapBench {
            frames: frames as usize,
            width,
            height,
            dim: dim as usize,
            log,
            config,
            budget,
            eval_keyframes: eval_keyframes as usize,
            json,
        }),
        Which::Ingest {
            width,
            height,
            regions,
            dim,
            frames,
            json,
        } => crate::bench_ingest::run(crate::bench_ingest::IngestBench {
            width,
            height,
            regions,
            dim,
            frames: frames as usize,
            json,
        }),
    }
}

#[derive(Serialize)]
pub(crate) struct Row {
    name: String,
    size: String,
    gpu_ms_median: f64,
    gpu_ms_min: f64,
    wall_ms_median: f64,
    pub throughput: f64,
    unit: &'static str,
}

#[derive(Serialize)]
struct Report {
    device: String,
    device_type: String,
    runs: usize,
    quick: bool,
    memory_bandwidth_gbps: f64,
    peak_gflops: f64,
    gemm_gflops: f64,
    primitives: Vec<Row>,
}

struct Timing {
    gpu_ms: Vec<f64>,
    wall_ms: Vec<f64>,
}

/// One kernel's share of a benchmarked operation.
#[derive(Serialize)]
pub(crate) struct KernelRow {
    pub name: String,
    /// Dispatches per run.
    pub count_per_run: f64,
    /// GPU milliseconds per run, mean over runs.
    pub ms_per_run: f64,
    pub mean_ms: f64,
    pub std_ms: f64,
    pub min_ms: f64,
    pub max_ms: f64,
}

/// Per-kernel statistics from the samples of `runs` measured runs, most
/// expensive first.
pub(crate) fn kernel_rows(
    per_kernel: std::collections::BTreeMap<&'static str, Vec<f64>>,
    runs: usize,
) -> Vec<KernelRow> {
    let mut rows: Vec<KernelRow> = per_kernel
        .into_iter()
        .map(|(name, v)| {
            let n = v.len() as f64;
            let mean = v.iter().sum::<f64>() / n;
            let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
            KernelRow {
                name: name.to_string(),
                count_per_run: n / runs as f64,
                ms_per_run: v.iter().sum::<f64>() / runs as f64,
                mean_ms: mean,
                std_ms: var.sqrt(),
                min_ms: v.iter().cloned().fold(f64::INFINITY, f64::min),
                max_ms: v.iter().cloned().fold(0.0, f64::max),
            }
        })
        .collect();
    rows.sort_by(|a, b| b.ms_per_run.total_cmp(&a.ms_per_run));
    rows
}

/// Prints the per-kernel table.
pub(crate) fn print_kernel_rows(rows: &[KernelRow]) {
    println!(
        "{:<28} {:>8} {:>12} {:>12} {:>10} {:>10} {:>10}",
        "kernel", "count", "ms/run", "mean ms", "std ms", "min ms", "max ms"
    );
    for k in rows {
        println!(
            "{:<28} {:>8.1} {:>12.3} {:>12.3} {:>10.3} {:>10.3} {:>10.3}",
            k.name, k.count_per_run, k.ms_per_run, k.mean_ms, k.std_ms, k.min_ms, k.max_ms
        );
    }
}

/// Writes a report as pretty JSON when a path was given.
pub(crate) fn write_json(path: Option<&std::path::Path>, report: &impl Serialize) -> Result<()> {
    if let Some(path) = path {
        let text = serde_json::to_string_pretty(report)?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// Median of a sample (NaN for an empty one).
pub(crate) fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// Runs `record` once to warm up and `runs` more times. With `skip_copies`,
/// buffer copies (set-up such as restoring inputs) are left out of the GPU
/// time.
fn time<'b>(
    ctx: &'b Context,
    runs: usize,
    skip_copies: bool,
    mut record: impl FnMut(&mut Recorder<'b>) -> latentam::Result<()>,
) -> Result<Timing> {
    let mut t = Timing {
        gpu_ms: Vec::new(),
        wall_ms: Vec::new(),
    };
    for i in 0..=runs {
        ctx.profiler_reset();
        let mut rec = ctx.recorder()?;
        record(&mut rec)?;
        let start = Instant::now();
        rec.submit()?.wait()?;
        let wall = start.elapsed().as_secs_f64() * 1e3;
        let gpu: f64 = ctx
            .profiler_snapshot()
            .samples()
            .iter()
            .filter(|s| !(skip_copies && s.name == "copy"))
            .map(|s| s.duration_ns * 1e-6)
            .sum();
        if i > 0 {
            t.gpu_ms.push(gpu);
            t.wall_ms.push(wall);
        }
    }
    Ok(t)
}

fn row(name: &str, size: String, t: &Timing, work: f64, unit: &'static str) -> Row {
    let med = median(&t.gpu_ms);
    Row {
        name: name.to_string(),
        size,
        gpu_ms_median: med,
        gpu_ms_min: t.gpu_ms.iter().cloned().fold(f64::INFINITY, f64::min),
        wall_ms_median: median(&t.wall_ms),
        throughput: work / (med * 1e-3),
        unit,
    }
}

/// Memory bandwidth: a buffer-to-buffer copy of `bytes` reads and writes
/// every byte (throughput in GB/s).
pub(crate) fn measure_bandwidth(ctx: &Context, bytes: u64, runs: usize) -> Result<Row> {
    let a = Buffer::device(ctx, "bench/copy_src", bytes)?;
    let b = Buffer::device(ctx, "bench/copy_dst", bytes)?;
    let t = time(ctx, runs, false, |rec| rec.copy(&a, 0, &b, 0, bytes))?;
    Ok(row(
        "copy",
        format!("{} MiB", bytes >> 20),
        &t,
        2.0 * bytes as f64 * 1e-9,
        "GB/s",
    ))
}

/// Attainable arithmetic rate: register-only multiply-adds over `groups`
/// workgroups of 256 invocations (throughput in GFLOP/s, an FMA counted as
/// two operations).
pub(crate) fn measure_fma_peak(ctx: &Context, groups: u32, runs: usize) -> Result<Row> {
    let iters = 2048u32;
    let sink = Buffer::device(ctx, "bench/sink", groups as u64 * 256 * 4)?;
    let p = latentam_shaders::push::FmaPeak { iters, seed: 0.5 };
    let t = time(ctx, runs, false, |rec| {
        rec.dispatch_linear(&latentam_shaders::FMA_PEAK, groups, &[&sink], &p)
    })?;
    let flops = groups as f64 * 256.0 * iters as f64 * 16.0;
    Ok(row(
        "fma_peak",
        format!("{} threads x {iters}", groups * 256),
        &t,
        flops * 1e-9,
        "GFLOP/s",
    ))
}

/// A context with timestamp profiling, or an error on devices without it.
pub(crate) fn profiling_context() -> Result<Context> {
    let ctx = Context::new(ContextOptions {
        profiling: true,
        ..ContextOptions::default()
    })?;
    if !ctx.profiling() {
        anyhow::bail!(
            "{} has no timestamp queries on its compute queue",
            ctx.info().name
        );
    }
    Ok(ctx)
}

fn primitives(json: Option<PathBuf>, runs: usize, quick: bool) -> Result<()> {
    let ctx = profiling_context()?;
    let div = if quick { 16 } else { 1 };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let mut rows = Vec::new();
    eprintln!("benchmarking on {} ({runs} runs each)...", ctx.info().name);

    let copy = measure_bandwidth(&ctx, (64u64 << 20) / div as u64, runs)?;
    rows.push(copy);
    let fma = measure_fma_peak(&ctx, 4096 / div, runs)?;
    let peak_gflops = fma.throughput;
    rows.push(fma);

    let n = 16_777_216u64 / div as u64;
    {
        let data: Vec<u32> = (0..n).map(|_| rng.random_range(0..4)).collect();
        let buf = ctx.upload_new("bench/scan", &data)?;
        let scan = PrefixScan::new(&ctx, n)?;
        let t = time(&ctx, runs, false, |rec| scan.record(rec, &buf, n))?;
        // One read and one write per element, plus a small second level.
        rows.push(row(
            "scan_u32",
            format!("{n}"),
            &t,
            8.0 * n as f64 * 1e-9,
            "GB/s",
        ));
    }
    {
        let data: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let src = ctx.upload_new("bench/reduce", &data)?;
        let dst = Buffer::device(&ctx, "bench/reduce_out", 4)?;
        let red = Reducer::new(&ctx, n)?;
        let t = time(&ctx, runs, false, |rec| {
            red.record(rec, ReduceOp::Sum, &src, n, &dst)
        })?;
        rows.push(row(
            "reduce_sum_f32",
            format!("{n}"),
            &t,
            4.0 * n as f64 * 1e-9,
            "GB/s",
        ));
    }

    for n in [1_048_576u64 / div as u64, 8_388_608u64 / div as u64] {
        let keys: Vec<u32> = (0..n).map(|_| rng.random()).collect();
        let vals: Vec<u32> = (0..n as u32).collect();
        let kb = ctx.upload_new("bench/keys", &keys)?;
        let vb = ctx.upload_new("bench/vals", &vals)?;
        let sorter = RadixSorter::new(&ctx, n)?;
        // Sorting sorted data is a different workload: restore the keys
        // before every run (the copy is not part of the timing below).
        let kb0 = ctx.upload_new("bench/keys0", &keys)?;
        // 32-bit keys take an even number of passes, so the sort itself
        // issues no copy.
        let t = time(&ctx, runs, true, |rec| {
            rec.copy(&kb0, 0, &kb, 0, n * 4)?;
            sorter.record(rec, &kb, &vb, n, 32)
        })?;
        rows.push(row(
            "radix_sort_kv",
            format!("{n} keys, 32 bits"),
            &t,
            n as f64 * 1e-6,
            "Mkeys/s",
        ));
    }

    let (m, nn, k) = (2000u32 / div, 2000u32 / div, 768u32);
    let mut best_gflops = 0.0f64;
    let device_type = ctx.info().device_type;
    for (name, tr) in [
        ("gemm_nn", Transpose::None),
        ("gemm_tn", Transpose::A),
        ("gemm_nt", Transpose::B),
    ] {
        let a: Vec<f32> = (0..m * k).map(|_| rng.random_range(-1.0..1.0)).collect();
        let b: Vec<f32> = (0..k * nn).map(|_| rng.random_range(-1.0..1.0)).collect();
        let ab = ctx.upload_new("bench/a", &a)?;
        let bb = ctx.upload_new("bench/b", &b)?;
        let cb = Buffer::device(&ctx, "bench/c", (m * nn * 4) as u64)?;
        let g = Gemm {
            transpose: tr,
            m,
            n: nn,
            k,
            alpha: 1.0,
            beta: 0.0,
        };
        // The kernel the engine uses on this device (row `gemm_nn`), then
        // the other one for comparison (`gemm_nn_tiled` / `_blocked`).
        let chosen = g.kernel_on(device_type);
        let other = match chosen {
            GemmKernel::Blocked => GemmKernel::Tiled,
            GemmKernel::Tiled => GemmKernel::Blocked,
        };
        for (kernel, label) in [
            (chosen, name.to_string()),
            (other, format!("{name}_{other:?}").to_lowercase()),
        ] {
            let t = time(&ctx, runs, false, |rec| {
                g.record_with(rec, kernel, &ab, &bb, &cb)
            })?;
            let r = row(
                &label,
                format!("{m}x{k}x{nn} {kernel:?}").to_lowercase(),
                &t,
                g.flops() * 1e-9,
                "GFLOP/s",
            );
            if kernel == chosen {
                best_gflops = best_gflops.max(r.throughput);
            }
            rows.push(r);
        }
    }

    {
        let (r_, c_) = (2000u32 / div, 2000u32);
        let x: Vec<f32> = (0..r_ * c_).map(|_| rng.random_range(-1.0..1.0)).collect();
        let xb = ctx.upload_new("bench/x", &x)?;
        let yb = Buffer::device(&ctx, "bench/y", (r_ * c_ * 4) as u64)?;
        let t = time(&ctx, runs, false, |rec| {
            ops::row_softmax(rec, &xb, &yb, r_, c_, 20.0)
        })?;
        rows.push(row(
            "softmax",
            format!("{r_}x{c_}"),
            &t,
            3.0 * 4.0 * (r_ * c_) as f64 * 1e-9,
            "GB/s",
        ));
    }

    {
        let n = 1_048_576u64 / div as u64;
        let values: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let targets: Vec<u32> = (0..n).map(|_| rng.random_range(0..10_000)).collect();
        let vb = ctx.upload_new("bench/values", &values)?;
        let tb = ctx.upload_new("bench/targets", &targets)?;
        let acc = Buffer::device(&ctx, "bench/acc", 10_000 * 4)?;
        let t = time(&ctx, runs, false, |rec| {
            ops::scatter_add_f32(rec, &vb, &tb, &acc, n)
        })?;
        let path = if ctx.info().native_float_atomics {
            "native"
        } else {
            "cas"
        };
        rows.push(row(
            &format!("scatter_add_f32_{path}"),
            format!("{n} into 10000 bins"),
            &t,
            n as f64 * 1e-6,
            "Madds/s",
        ));
    }

    println!("device: {} ({:?})", ctx.info().name, ctx.info().device_type);
    println!(
        "{:<24} {:<24} {:>12} {:>12} {:>12} {:>14}",
        "primitive", "size", "median ms", "min ms", "wall ms", "throughput"
    );
    for r in &rows {
        println!(
            "{:<24} {:<24} {:>12.3} {:>12.3} {:>12.3} {:>8.2} {}",
            r.name, r.size, r.gpu_ms_median, r.gpu_ms_min, r.wall_ms_median, r.throughput, r.unit
        );
    }
    let report = Report {
        device: ctx.info().name.clone(),
        device_type: format!("{:?}", ctx.info().device_type),
        runs,
        quick,
        memory_bandwidth_gbps: rows[0].throughput,
        peak_gflops,
        gemm_gflops: best_gflops,
        primitives: rows,
    };
    println!(
        "memory bandwidth (copy): {:.2} GB/s; arithmetic peak (FMA): {:.2} GFLOP/s; best GEMM: \
         {:.2} GFLOP/s ({:.1} % of the FMA peak)",
        report.memory_bandwidth_gbps,
        report.peak_gflops,
        report.gemm_gflops,
        100.0 * report.gemm_gflops / report.peak_gflops.max(1e-9)
    );
    write_json(json.as_deref(), &report)
}
