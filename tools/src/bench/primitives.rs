//! `latentam bench primitives`: every GPU primitive at the sizes the
//! mapper uses.

use std::path::PathBuf;

use anyhow::Result;
use latentam_gpu::ops::{
    self, Gemm, GemmKernel, PrefixScan, RadixSorter, ReduceOp, Reducer, Transpose,
};
use latentam_gpu::{Buffer, Context};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::common::{
    measure_bandwidth, measure_fma_peak, profiling_context, row, time, write_json, Row,
};

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

pub fn run(json: Option<PathBuf>, runs: usize, quick: bool) -> Result<()> {
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
    rows.push(bench_scan(&ctx, &mut rng, n, runs)?);
    rows.push(bench_reduce(&ctx, &mut rng, n, runs)?);
    for n in [1_048_576u64 / div as u64, 8_388_608u64 / div as u64] {
        rows.push(bench_sort(&ctx, &mut rng, n, runs)?);
    }
    let (gemms, best_gflops) = bench_gemms(&ctx, &mut rng, div, runs)?;
    rows.extend(gemms);
    rows.push(bench_softmax(&ctx, &mut rng, div, runs)?);
    rows.push(bench_scatter_add(&ctx, &mut rng, div, runs)?);

    print_rows(&ctx, &rows);
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

/// A prefix sum over `n` u32s: one read and one write per element, plus
/// a small second level.
fn bench_scan(ctx: &Context, rng: &mut ChaCha8Rng, n: u64, runs: usize) -> Result<Row> {
    let data: Vec<u32> = (0..n).map(|_| rng.random_range(0..4)).collect();
    let buf = ctx.upload_new("bench/scan", &data)?;
    let scan = PrefixScan::new(ctx, n)?;
    let t = time(ctx, runs, false, |rec| scan.record(rec, &buf, n))?;
    Ok(row(
        "scan_u32",
        format!("{n}"),
        &t,
        8.0 * n as f64 * 1e-9,
        "GB/s",
    ))
}

/// A sum over `n` floats.
fn bench_reduce(ctx: &Context, rng: &mut ChaCha8Rng, n: u64, runs: usize) -> Result<Row> {
    let data: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let src = ctx.upload_new("bench/reduce", &data)?;
    let dst = Buffer::device(ctx, "bench/reduce_out", 4)?;
    let red = Reducer::new(ctx, n)?;
    let t = time(ctx, runs, false, |rec| {
        red.record(rec, ReduceOp::Sum, &src, n, &dst)
    })?;
    Ok(row(
        "reduce_sum_f32",
        format!("{n}"),
        &t,
        4.0 * n as f64 * 1e-9,
        "GB/s",
    ))
}

/// A 32-bit key-value radix sort of `n` random keys.
fn bench_sort(ctx: &Context, rng: &mut ChaCha8Rng, n: u64, runs: usize) -> Result<Row> {
    let keys: Vec<u32> = (0..n).map(|_| rng.random()).collect();
    let vals: Vec<u32> = (0..n as u32).collect();
    let kb = ctx.upload_new("bench/keys", &keys)?;
    let vb = ctx.upload_new("bench/vals", &vals)?;
    let sorter = RadixSorter::new(ctx, n)?;
    // Sorting sorted data is a different workload: restore the keys
    // before every run (the copy is not part of the timing below).
    let kb0 = ctx.upload_new("bench/keys0", &keys)?;
    // 32-bit keys take an even number of passes, so the sort itself
    // issues no copy.
    let t = time(ctx, runs, true, |rec| {
        rec.copy(&kb0, 0, &kb, 0, n * 4)?;
        sorter.record(rec, &kb, &vb, n, 32)
    })?;
    Ok(row(
        "radix_sort_kv",
        format!("{n} keys, 32 bits"),
        &t,
        n as f64 * 1e-6,
        "Mkeys/s",
    ))
}

/// The GEMMs the decoder runs (K = 2000 atoms against 768-d rows), in
/// the kernel the engine picks on this device and the other one; the rows
/// and the chosen kernels' best rate in GFLOP/s.
fn bench_gemms(
    ctx: &Context,
    rng: &mut ChaCha8Rng,
    div: u32,
    runs: usize,
) -> Result<(Vec<Row>, f64)> {
    let mut rows = Vec::new();
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
        let cb = Buffer::device(ctx, "bench/c", (m * nn * 4) as u64)?;
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
            let t = time(ctx, runs, false, |rec| {
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
    Ok((rows, best_gflops))
}

/// A row softmax over 2000 columns.
fn bench_softmax(ctx: &Context, rng: &mut ChaCha8Rng, div: u32, runs: usize) -> Result<Row> {
    let (r_, c_) = (2000u32 / div, 2000u32);
    let x: Vec<f32> = (0..r_ * c_).map(|_| rng.random_range(-1.0..1.0)).collect();
    let xb = ctx.upload_new("bench/x", &x)?;
    let yb = Buffer::device(ctx, "bench/y", (r_ * c_ * 4) as u64)?;
    let t = time(ctx, runs, false, |rec| {
        ops::row_softmax(rec, &xb, &yb, r_, c_, 20.0)
    })?;
    Ok(row(
        "softmax",
        format!("{r_}x{c_}"),
        &t,
        3.0 * 4.0 * (r_ * c_) as f64 * 1e-9,
        "GB/s",
    ))
}

/// `n` float additions scattered into 10 000 bins, with native float
/// atomics or the compare-and-swap loop, whichever the device takes.
fn bench_scatter_add(ctx: &Context, rng: &mut ChaCha8Rng, div: u32, runs: usize) -> Result<Row> {
    let n = 1_048_576u64 / div as u64;
    let values: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let targets: Vec<u32> = (0..n).map(|_| rng.random_range(0..10_000)).collect();
    let vb = ctx.upload_new("bench/values", &values)?;
    let tb = ctx.upload_new("bench/targets", &targets)?;
    let acc = Buffer::device(ctx, "bench/acc", 10_000 * 4)?;
    let t = time(ctx, runs, false, |rec| {
        ops::scatter_add_f32(rec, &vb, &tb, &acc, n)
    })?;
    let path = if ctx.info().native_float_atomics {
        "native"
    } else {
        "cas"
    };
    Ok(row(
        &format!("scatter_add_f32_{path}"),
        format!("{n} into 10000 bins"),
        &t,
        n as f64 * 1e-6,
        "Madds/s",
    ))
}

/// The table of `rows`.
fn print_rows(ctx: &Context, rows: &[Row]) {
    println!("device: {} ({:?})", ctx.info().name, ctx.info().device_type);
    println!(
        "{:<24} {:<24} {:>12} {:>12} {:>12} {:>14}",
        "primitive", "size", "median ms", "min ms", "wall ms", "throughput"
    );
    for r in rows {
        println!(
            "{:<24} {:<24} {:>12.3} {:>12.3} {:>12.3} {:>8.2} {}",
            r.name, r.size, r.gpu_ms_median, r.gpu_ms_min, r.wall_ms_median, r.throughput, r.unit
        );
    }
}
