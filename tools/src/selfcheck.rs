//! `latentam devices` and `latentam selfcheck`.
//!
//! Unlike the rest of the tool, which uses the `latentam` façade alone,
//! this module reaches into `latentam-gpu` (its primitives, buffers and
//! validation), the kernel table of `latentam-shaders` and the CPU
//! reference: it checks the layers themselves, below what the façade
//! exports.

use anyhow::{bail, Context as _, Result};
use latentam_gpu::ops::{self, Gemm, PrefixScan, RadixSorter, ReduceOp, Reducer, Transpose};
use latentam_gpu::{Buffer, Context, ContextOptions, Validation};
use rand::{Rng, SeedableRng};

pub fn devices() -> Result<()> {
    let ctx = Context::new(ContextOptions::default())?;
    let i = ctx.info();
    println!("selected device: {}", i.name);
    println!("  type:                  {:?}", i.device_type);
    println!(
        "  Vulkan:                {}.{}.{}",
        ash_major(i.api_version),
        (i.api_version >> 12) & 0x3ff,
        i.api_version & 0xfff
    );
    println!("  native float atomics:  {}", i.native_float_atomics);
    println!("  subgroup size:         {}", i.subgroup_size);
    println!(
        "  timestamps:            {}",
        i.timestamp_period_ns.is_some()
    );
    println!("  dedicated transfer:    {}", i.dedicated_transfer_queue);
    println!(
        "  max storage buffer:    {} MiB",
        i.max_storage_buffer_range >> 20
    );
    println!(
        "  max allocation:        {} MiB",
        i.max_memory_allocation_size >> 20
    );
    println!(
        "  device-local memory:   {} MiB",
        i.device_local_bytes >> 20
    );
    match &i.pipeline_cache_file {
        Some(f) => println!(
            "  pipeline cache:        {} ({} bytes found)",
            f.display(),
            i.pipeline_cache_loaded_bytes
        ),
        None => println!("  pipeline cache:        off"),
    }
    println!("set LATENTAM_DEVICE=<index or name> to choose another device");
    Ok(())
}

fn ash_major(v: u32) -> u32 {
    v >> 22
}

struct Check {
    name: &'static str,
    ok: bool,
    detail: String,
}

pub fn run(
    validation: bool,
    kernel_times: Option<&std::path::Path>,
    only: &[String],
) -> Result<()> {
    let opts = ContextOptions {
        validation: if validation {
            Validation::Required
        } else {
            ContextOptions::default().validation
        },
        ..ContextOptions::default()
    };
    let ctx = Context::new(opts)?;
    let log = ctx.validation_log();
    println!("device: {}", ctx.info().name);
    let kernels = check_kernels(&ctx, only);
    if let Some(path) = kernel_times {
        write_kernel_times(&ctx, path)?;
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    // A chosen few kernels are built alone: the primitives' checks would
    // build theirs too.
    let checks = if only.is_empty() {
        vec![
            kernels,
            check_scan(&ctx, &mut rng).context("scan")?,
            check_reduce(&ctx, &mut rng).context("reduce")?,
            check_gemm(&ctx, &mut rng).context("gemm")?,
            check_softmax(&ctx, &mut rng).context("softmax")?,
            check_sort(&ctx, &mut rng).context("sort")?,
            check_atomic(&ctx, &mut rng).context("scatter-add")?,
        ]
    } else {
        vec![kernels]
    };
    drop(ctx);
    let mut failed = 0;
    for c in &checks {
        println!(
            "  {:<12} {:<4} {}",
            c.name,
            if c.ok { "ok" } else { "FAIL" },
            c.detail
        );
        failed += usize::from(!c.ok);
    }
    let errors = log.errors();
    if !errors.is_empty() {
        bail!(
            "{} Vulkan validation error(s):\n{}",
            errors.len(),
            errors.join("\n")
        );
    }
    if failed > 0 {
        bail!("{failed} check(s) failed");
    }
    if only.is_empty() {
        println!(
            "the kernels build, and all {} primitives match their CPU references",
            checks.len() - 1
        );
    } else {
        println!("the chosen kernels build");
    }
    Ok(())
}

/// Builds every kernel the device can run as the mapper does before it is
/// ready (pipelines created on all cores, each dispatched once empty: see
/// `Context::warm_up`), and names every kernel that fails. A GPU's
/// compiler may reject the largest column-layout blending kernels: the
/// rasterizer then takes the pixel ones, so those are noted, not failed.
fn check_kernels(ctx: &Context, only: &[String]) -> Check {
    let start = std::time::Instant::now();
    let mut failed = Vec::new();
    let chosen = |k: &latentam_shaders::Kernel| {
        only.is_empty() || only.iter().any(|o| k.name.contains(o.as_str()))
    };
    if let Err(e) = ctx.warm_up_only(chosen) {
        failed.push(format!("building stopped: {e}"));
    }
    let wall = start.elapsed().as_secs_f64();
    let mut fall_back = Vec::new();
    for (name, result) in ctx.kernel_build_failures() {
        let column = latentam_shaders::ALL
            .iter()
            .any(|k| k.name == name && k.is_column_layout());
        if !ctx.info().is_cpu() && column {
            fall_back.push(name.to_string());
        } else {
            failed.push(format!("{name}: the driver cannot build it ({result})"));
        }
    }
    let mut built = ctx.kernel_build_times();
    built.sort_by(|a, b| b.total_ms().total_cmp(&a.total_ms()));
    let total: f64 = built.iter().map(|b| b.total_ms()).sum::<f64>() / 1e3;
    let slowest: Vec<String> = built
        .iter()
        .take(3)
        .map(|b| format!("{} {:.2} s", b.kernel, b.total_ms() / 1e3))
        .collect();
    let mut detail = format!(
        "{} built in {wall:.1} s on {} threads, {total:.1} s of work (slowest: {})",
        built.len(),
        std::thread::available_parallelism().map_or(1, |n| n.get()),
        slowest.join(", ")
    );
    for f in &fall_back {
        detail.push_str(&format!(
            "\n               rejected, the pixel layout stands in: {f}"
        ));
    }
    for f in &failed {
        detail.push_str(&format!("\n               failed: {f}"));
    }
    Check {
        name: "kernels",
        ok: failed.is_empty(),
        detail,
    }
}

/// The per-kernel build table: printed slowest first and written as JSON.
fn write_kernel_times(ctx: &Context, path: &std::path::Path) -> Result<()> {
    let mut times = ctx.kernel_build_times();
    times.sort_by(|a, b| b.total_ms().total_cmp(&a.total_ms()));
    println!("kernel build times, slowest first (create + first dispatch, ms):");
    for t in &times {
        println!(
            "  {:<40} {:>9.1} = {:>7.1} + {:>9.1}",
            t.kernel,
            t.total_ms(),
            t.create_ms,
            t.first_dispatch_ms
        );
    }
    let rows: Vec<serde_json::Value> = times
        .iter()
        .map(|t| {
            serde_json::json!({
                "kernel": t.kernel,
                "create_ms": t.create_ms,
                "first_dispatch_ms": t.first_dispatch_ms,
            })
        })
        .collect();
    let doc = serde_json::json!({
        "device": ctx.info().name,
        "threads": std::thread::available_parallelism().map_or(1, |n| n.get()),
        "pipeline_cache_loaded_bytes": ctx.info().pipeline_cache_loaded_bytes,
        "time_to_ready_ms": ctx.time_to_ready_ms(),
        "kernels": rows,
    });
    std::fs::write(path, serde_json::to_string_pretty(&doc)?)
        .with_context(|| format!("writing {}", path.display()))?;
    println!("wrote {}", path.display());
    Ok(())
}

fn check_scan(ctx: &Context, r: &mut impl Rng) -> Result<Check> {
    let data: Vec<u32> = (0..300_001).map(|_| r.random_range(0..100)).collect();
    let buf = ctx.upload_new("check/scan", &data)?;
    let scan = PrefixScan::new(ctx, data.len() as u64)?;
    let mut rec = ctx.recorder()?;
    scan.record(&mut rec, &buf, data.len() as u64)?;
    rec.submit()?.wait()?;
    let ok = ctx.download::<u32>(&buf)? == latentam_reference::scan::exclusive_scan_u32(&data);
    Ok(Check {
        name: "scan",
        ok,
        detail: format!("{} elements", data.len()),
    })
}

fn check_reduce(ctx: &Context, r: &mut impl Rng) -> Result<Check> {
    let data: Vec<f32> = (0..1_000_003).map(|_| r.random_range(-1.0..1.0)).collect();
    let src = ctx.upload_new("check/reduce", &data)?;
    let dst = Buffer::device(ctx, "check/reduce_out", 8)?;
    let red = Reducer::new(ctx, data.len() as u64)?;
    let mut rec = ctx.recorder()?;
    red.record(&mut rec, ReduceOp::Sum, &src, data.len() as u64, &dst)?;
    rec.submit()?.wait()?;
    let got = ctx.download::<f32>(&dst)?[0] as f64;
    let want = latentam_reference::reduce::sum(&data);
    let err = (got - want).abs();
    Ok(Check {
        name: "reduce",
        ok: err < 1e-1,
        detail: format!("sum error {err:.2e}"),
    })
}

fn check_gemm(ctx: &Context, r: &mut impl Rng) -> Result<Check> {
    let (m, n, k) = (70u32, 90u32, 130u32);
    let mut worst = 0.0f32;
    for t in [Transpose::None, Transpose::A, Transpose::B] {
        let a: Vec<f32> = (0..m * k).map(|_| r.random_range(-1.0..1.0)).collect();
        let b: Vec<f32> = (0..k * n).map(|_| r.random_range(-1.0..1.0)).collect();
        let ab = ctx.upload_new("check/a", &a)?;
        let bb = ctx.upload_new("check/b", &b)?;
        let cb = Buffer::device(ctx, "check/c", (m * n * 4) as u64)?;
        let mut rec = ctx.recorder()?;
        Gemm {
            transpose: t,
            m,
            n,
            k,
            alpha: 1.0,
            beta: 0.0,
        }
        .record(&mut rec, &ab, &bb, &cb)?;
        rec.submit()?.wait()?;
        let got = ctx.download::<f32>(&cb)?;
        let mut want = vec![0.0f32; (m * n) as usize];
        let layout = match t {
            Transpose::None => latentam_reference::gemm::Transpose::None,
            Transpose::A => latentam_reference::gemm::Transpose::A,
            Transpose::B => latentam_reference::gemm::Transpose::B,
        };
        latentam_reference::gemm::gemm(
            layout, m as usize, n as usize, k as usize, 1.0, &a, &b, 0.0, &mut want,
        );
        for (g, w) in got.iter().zip(&want) {
            worst = worst.max((g - w).abs());
        }
    }
    Ok(Check {
        name: "gemm",
        ok: worst < 1e-3,
        detail: format!("max error {worst:.2e}"),
    })
}

fn check_softmax(ctx: &Context, r: &mut impl Rng) -> Result<Check> {
    let (rows, cols) = (50u32, 2000u32);
    let x: Vec<f32> = (0..rows * cols)
        .map(|_| r.random_range(-1.0..1.0))
        .collect();
    let xb = ctx.upload_new("check/x", &x)?;
    let yb = Buffer::device(ctx, "check/y", (rows * cols * 4) as u64)?;
    let mut rec = ctx.recorder()?;
    ops::row_softmax(&mut rec, &xb, &yb, rows, cols, 20.0)?;
    rec.submit()?.wait()?;
    let got = ctx.download::<f32>(&yb)?;
    let want = latentam_reference::softmax::row_softmax(&x, rows as usize, cols as usize, 20.0);
    let worst = got
        .iter()
        .zip(&want)
        .map(|(g, w)| ((*g as f64 - w) / w.max(1e-6)).abs())
        .fold(0.0, f64::max);
    Ok(Check {
        name: "softmax",
        ok: worst < 1e-3,
        detail: format!("max rel. error {worst:.2e}"),
    })
}

fn check_sort(ctx: &Context, r: &mut impl Rng) -> Result<Check> {
    let n = 500_000u64;
    let keys: Vec<u32> = (0..n).map(|_| r.random_range(0..1000)).collect();
    let vals: Vec<u32> = (0..n as u32).collect();
    let kb = ctx.upload_new("check/keys", &keys)?;
    let vb = ctx.upload_new("check/vals", &vals)?;
    let sorter = RadixSorter::new(ctx, n)?;
    let mut rec = ctx.recorder()?;
    sorter.record(&mut rec, &kb, &vb, n, 32)?;
    rec.submit()?.wait()?;
    let (wk, wv) = latentam_reference::sort::sort_pairs(&keys, &vals, 32);
    let ok = ctx.download::<u32>(&kb)? == wk && ctx.download::<u32>(&vb)? == wv;
    Ok(Check {
        name: "sort",
        ok,
        detail: format!("{n} pairs, stable"),
    })
}

fn check_atomic(ctx: &Context, r: &mut impl Rng) -> Result<Check> {
    let n = 100_000usize;
    let values: Vec<f32> = (0..n).map(|_| r.random_range(-1.0..1.0)).collect();
    let targets: Vec<u32> = (0..n).map(|_| r.random_range(0..64)).collect();
    let vb = ctx.upload_new("check/values", &values)?;
    let tb = ctx.upload_new("check/targets", &targets)?;
    let acc = Buffer::device(ctx, "check/acc", 64 * 4)?;
    let mut rec = ctx.recorder()?;
    rec.fill_u32(&acc, 0);
    ops::scatter_add_f32(&mut rec, &vb, &tb, &acc, n as u64)?;
    rec.submit()?.wait()?;
    let got = ctx.download::<f32>(&acc)?;
    let want = latentam_reference::atomic::scatter_add(&values, &targets, 64);
    let worst = got
        .iter()
        .zip(&want)
        .map(|(g, w)| (*g as f64 - w).abs())
        .fold(0.0, f64::max);
    let path = if ctx.info().native_float_atomics {
        "native"
    } else {
        "CAS"
    };
    Ok(Check {
        name: "scatter-add",
        ok: worst < 1e-2,
        detail: format!("{path} float atomics, max error {worst:.2e}"),
    })
}
