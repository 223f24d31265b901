//! What the benchmarks share: timing a recorded operation, per-kernel
//! tables, the machine's bandwidth and arithmetic rate, JSON output.

use std::time::Instant;

use anyhow::{Context as _, Result};
use latentam_gpu::{Buffer, Context, ContextOptions, Recorder};
use latentam_shaders::bind;
use serde::Serialize;

#[derive(Serialize)]
pub(crate) struct Row {
    pub name: String,
    pub size: String,
    pub gpu_ms_median: f64,
    pub gpu_ms_min: f64,
    pub wall_ms_median: f64,
    pub throughput: f64,
    pub unit: &'static str,
}

pub(crate) struct Timing {
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
pub(crate) fn time<'b>(
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

pub(crate) fn row(name: &str, size: String, t: &Timing, work: f64, unit: &'static str) -> Row {
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
        rec.dispatch_linear(
            &latentam_shaders::FMA_PEAK,
            groups,
            bind::FmaPeakBuffers { sink: &sink },
            &p,
        )
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
