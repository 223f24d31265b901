//! `latentam bench latent`: the latent head at the paper's sizes — the
//! attention decoder forward and backward, one Stage II iteration (decode,
//! feature loss, backward, trust region, Adam on W and D), one streaming
//! k-means update on a full dictionary, and SSIM forward + backward on one
//! image.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Result;
use latentam_core::latent::{
    AttentionDecoder, DecoderConfig, DecoderGrads, DecoderParams, KMeansConfig, StreamingKMeans,
};
use latentam_core::loss::{
    mean_per_view_weights, FeatureLoss, ImageLoss, LossWeights, TrustRegion,
};
use latentam_core::optim::{AdamGroup, AdamHyper};
use latentam_core::splat::{BatchLayout, Camera, QUERY_DIM};
use latentam_gpu::{Buffer, Context, Floor, GpuModel, Sample};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::common::{
    kernel_rows, median, print_kernel_rows, profiling_context, write_json, KernelRow,
};

/// Settings of one latent-head benchmark.
pub struct LatentBench {
    pub regions: u32,
    pub atoms: u32,
    pub dim: u32,
    pub ssim_width: u32,
    pub ssim_height: u32,
    pub runs: usize,
    pub json: Option<PathBuf>,
}

#[derive(Serialize)]
struct Report {
    device: String,
    regions: u32,
    atoms: u32,
    dim: u32,
    ssim_width: u32,
    ssim_height: u32,
    runs: usize,
    decode_forward_ms_median: f64,
    decode_backward_ms_median: f64,
    /// Multiply-adds ×2 of decoder forward + backward over their median time.
    decode_gflops: f64,
    stage2_iteration_ms_median: f64,
    /// Regions of concepts the dictionary has not seen.
    kmeans_ms_median: f64,
    /// Regions near atoms already in the dictionary.
    kmeans_familiar_ms_median: f64,
    ssim_forward_backward_ms_median: f64,
    image_loss_ms_median: f64,
    /// The floor of one Stage II iteration on each GPU model, from its
    /// work counted from launch sizes (`latentam_gpu::GpuModel::floor`).
    stage2_iteration_floor: Vec<Floor>,
    /// The same for one full-dictionary k-means update (the mean of the
    /// new-concept and familiar runs).
    kmeans_floor: Vec<Floor>,
    kernels: Vec<KernelRow>,
}

/// Runs `op` and the floor per run of the work it recorded (it runs the
/// measured operation `runs + 1` times, the first to warm up).
fn with_floor<T>(
    ctx: &Context,
    runs: f64,
    op: impl FnOnce() -> Result<T>,
) -> Result<(T, Vec<Floor>)> {
    let (work, calls) = (ctx.gpu_work(), ctx.gpu_calls());
    let out = op()?;
    let (work, calls) = (ctx.gpu_work() - work, ctx.gpu_calls() - calls);
    let floors = GpuModel::presets()
        .iter()
        .map(|m| m.floor(&work, calls, runs))
        .collect();
    Ok((out, floors))
}

fn random_buffer(
    ctx: &Context,
    name: &str,
    n: usize,
    scale: f32,
    rng: &mut impl Rng,
) -> Result<Buffer> {
    let v: Vec<f32> = (0..n).map(|_| rng.random_range(-scale..scale)).collect();
    Ok(ctx.upload_new(name, &v)?)
}

/// Rows of unit vectors, clustered around a few directions like real
/// region embeddings.
fn unit_rows(rows: usize, dim: usize, rng: &mut impl Rng) -> Vec<f32> {
    let centres = directions(dim, rng);
    rows_around(&centres, rows, rng)
}

/// 32 random directions in `dim` dimensions (nearly orthogonal).
pub(super) fn directions(dim: usize, rng: &mut impl Rng) -> Vec<Vec<f32>> {
    (0..32)
        .map(|_| (0..dim).map(|_| rng.random_range(-1.0..1.0)).collect())
        .collect()
}

/// Unit rows each near one of `centres` (cosine about 0.8 to it).
pub(super) fn rows_around(centres: &[Vec<f32>], rows: usize, rng: &mut impl Rng) -> Vec<f32> {
    let dim = centres[0].len();
    let mut out = Vec::with_capacity(rows * dim);
    for _ in 0..rows {
        let c = &centres[rng.random_range(0..centres.len())];
        let v: Vec<f32> = c.iter().map(|x| x + rng.random_range(-0.5..0.5)).collect();
        let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        out.extend(v.iter().map(|x| x / n));
    }
    out
}

/// Runs `record` once to warm up and `runs` times measured; returns the
/// median GPU time and adds every kernel's samples to `per_kernel`.
fn time(
    ctx: &Context,
    runs: usize,
    per_kernel: &mut BTreeMap<&'static str, Vec<f64>>,
    op: impl FnMut() -> latentam::Result<()>,
) -> Result<f64> {
    time_after(ctx, runs, per_kernel, || Ok(()), op)
}

/// [`time`] with `setup` run, untimed, before each run of `op`.
fn time_after(
    ctx: &Context,
    runs: usize,
    per_kernel: &mut BTreeMap<&'static str, Vec<f64>>,
    mut setup: impl FnMut() -> latentam::Result<()>,
    mut op: impl FnMut() -> latentam::Result<()>,
) -> Result<f64> {
    let mut times = Vec::new();
    let mut progress = latentam_cli::progress::Progress::new("bench latent", runs + 1);
    for run in 0..=runs {
        progress.set(run);
        setup()?;
        ctx.profiler_reset();
        op()?;
        let samples: Vec<Sample> = ctx.profiler_snapshot().samples().to_vec();
        if run > 0 {
            times.push(samples.iter().map(|s| s.duration_ns * 1e-6).sum());
            for s in samples {
                per_kernel
                    .entry(s.name)
                    .or_default()
                    .push(s.duration_ns * 1e-6);
            }
        }
    }
    progress.set(runs + 1);
    Ok(median(&times))
}

/// Streaming k-means on a full dictionary (the expensive regime), for
/// regions of new concepts and of familiar ones: the medians in ms.
fn kmeans_times(
    ctx: &Context,
    b: &LatentBench,
    rng: &mut ChaCha8Rng,
    per_kernel: &mut BTreeMap<&'static str, Vec<f64>>,
) -> Result<(f64, f64)> {
    let (n, k, d) = (b.regions as usize, b.atoms as usize, b.dim as usize);
    let kcfg = KMeansConfig {
        atoms: b.atoms,
        dim: b.dim,
        max_points: b.regions.max(1),
        ..Default::default()
    };
    let kmeans = StreamingKMeans::new(ctx, kcfg)?;
    // Regions of as many concepts the dictionary knows as the keyframe has
    // micro-clusters (each micro-centre lands near atoms: no new concept),
    // and regions in new directions (every micro-centre a new concept,
    // which also needs the atoms' own K × K cosines).
    let seen = directions(d, rng);
    let atoms_host = rows_around(&seen, k, rng);
    let kd = ctx.upload_new("bench/kmeans_atoms", &atoms_host)?;
    let k_anchor = Buffer::device(ctx, "bench/kmeans_anchor", (k * d * 4) as u64)?;
    let moved = Buffer::device(ctx, "bench/moved", (k * 4) as u64)?;
    let known = &seen[..kcfg.micro_clusters.min(seen.len() as u32) as usize];
    let familiar = ctx.upload_new("bench/familiar", &rows_around(known, n, rng))?;
    let novel = ctx.upload_new("bench/novel", &unit_rows(n, d, rng))?;
    let full_weights = vec![1.0f32; k];
    let mut kmeans_time = |features: &Buffer| {
        let reset = || {
            ctx.upload(&kd, 0, &atoms_host)?;
            kmeans.restore(ctx, b.atoms, &full_weights)
        };
        time_after(ctx, b.runs, per_kernel, reset, || {
            let mut rec = ctx.recorder()?;
            kmeans.record_update(&mut rec, features, None, b.regions, &kd, &k_anchor, &moved)?;
            rec.submit()?.wait()
        })
    };
    Ok((kmeans_time(&novel)?, kmeans_time(&familiar)?))
}

/// The image losses on one view, and SSIM alone (the sum of its four
/// passes): the medians in ms.
fn image_loss_times(
    ctx: &Context,
    b: &LatentBench,
    rng: &mut ChaCha8Rng,
    weights: LossWeights,
    per_kernel: &mut BTreeMap<&'static str, Vec<f64>>,
) -> Result<(f64, f64)> {
    let layout = BatchLayout::for_cameras(&[Camera::at_origin(b.ssim_width, b.ssim_height)])?;
    let pixels = layout.pixels;
    let img = |rng: &mut rand_chacha::ChaCha8Rng| -> Vec<[f32; 4]> {
        (0..pixels)
            .map(|_| {
                [
                    rng.random_range(0.0..1.0),
                    rng.random_range(0.0..1.0),
                    rng.random_range(0.0..1.0),
                    2.0,
                ]
            })
            .collect()
    };
    let rendered = ctx.upload_new("bench/rendered", &img(rng))?;
    let target = ctx.upload_new("bench/target", &img(rng))?;
    let grad_img = Buffer::device(ctx, "bench/grad_image", pixels * 16)?;
    let image_loss = ImageLoss::new(ctx, pixels, 1, weights)?;
    let mut image_kernels = BTreeMap::new();
    let image_ms = time(ctx, b.runs, &mut image_kernels, || {
        let mut rec = ctx.recorder()?;
        image_loss.record(&mut rec, &layout, &rendered, &target, &[pixels], &grad_img)?;
        rec.submit()?.wait()
    })?;
    let ssim_runs: Vec<f64> = (0..b.runs)
        .map(|r| {
            image_kernels
                .iter()
                .filter(|(name, _)| name.starts_with("ssim_"))
                .map(|(_, v)| v[r])
                .sum()
        })
        .collect();
    for (name, v) in image_kernels {
        per_kernel.entry(name).or_default().extend(v);
    }
    Ok((image_ms, median(&ssim_runs)))
}

/// Floating-point operations of one decoder forward and backward pass
/// over `n` regions, `k` atoms and `d`-d embeddings. Forward: E, S, F.
/// Backward: dA, dD, dÊ, dD̂, dW, dQ.
fn decode_flops(n: usize, k: usize, d: usize) -> f64 {
    let (n, k, d, s) = (n as f64, k as f64, d as f64, QUERY_DIM as f64);
    2.0 * (n * s * d + 2.0 * n * k * d) + 2.0 * (4.0 * n * k * d + 2.0 * n * s * d)
}

/// The report's figures on the terminal (the kernel table apart).
fn print_report(r: &Report) {
    println!(
        "device: {}\ndecoder n={} K={} d_f={}: forward {:.3} ms, backward {:.3} ms GPU (median), \
         {:.2} GFLOP/s",
        r.device,
        r.regions,
        r.atoms,
        r.dim,
        r.decode_forward_ms_median,
        r.decode_backward_ms_median,
        r.decode_gflops
    );
    println!(
        "Stage II iteration (decode, feature loss, backward, trust region, Adam W+D): {:.3} ms",
        r.stage2_iteration_ms_median
    );
    println!(
        "streaming k-means, full dictionary, {} regions: new concepts {:.3} ms, familiar ones \
         {:.3} ms",
        r.regions, r.kmeans_ms_median, r.kmeans_familiar_ms_median
    );
    println!(
        "image loss {}x{}: {:.3} ms (SSIM forward+backward {:.3} ms)",
        r.ssim_width, r.ssim_height, r.image_loss_ms_median, r.ssim_forward_backward_ms_median
    );
    for (what, floors) in [
        ("a Stage II iteration", &r.stage2_iteration_floor),
        ("a full-dictionary k-means update", &r.kmeans_floor),
    ] {
        for f in floors {
            println!(
                "floor of {what} on {}: {:.3} ms (kernels {:.3}, dispatches {:.3}, host waits {:.3}, host link {:.3})",
                f.gpu, f.total_ms, f.kernels_ms, f.dispatch_ms, f.host_wait_ms, f.link_ms
            );
        }
    }
}

/// A decoder sized for the benchmark's regions, atoms and dimension.
fn decoder(ctx: &Context, b: &LatentBench) -> Result<AttentionDecoder> {
    let config = DecoderConfig {
        max_regions: b.regions,
        max_atoms: b.atoms,
        dim: b.dim,
        ..Default::default()
    };
    Ok(AttentionDecoder::new(ctx, config)?)
}

pub fn run(b: LatentBench) -> Result<()> {
    let ctx = profiling_context()?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let (n, k, d) = (b.regions as usize, b.atoms as usize, b.dim as usize);
    let weights = LossWeights::default();

    let dec = decoder(&ctx, &b)?;
    let queries = random_buffer(&ctx, "bench/queries", n * QUERY_DIM, 1.0, &mut rng)?;
    let w = random_buffer(&ctx, "bench/W", QUERY_DIM * d, 1.0, &mut rng)?;
    let atoms = ctx.upload_new("bench/D", &unit_rows(k, d, &mut rng))?;
    let anchor = ctx.upload_new("bench/D0", &unit_rows(k, d, &mut rng))?;
    let targets = ctx.upload_new("bench/targets", &unit_rows(n, d, &mut rng))?;
    let row_weights = ctx.upload_new("bench/row_weights", &mean_per_view_weights(&[b.regions]))?;
    let grad_out = random_buffer(&ctx, "bench/dF", n * d, 1.0, &mut rng)?;
    let grad_q = Buffer::device(&ctx, "bench/dQ", (n * QUERY_DIM * 4) as u64)?;
    let grad_w = Buffer::device(&ctx, "bench/dW", (QUERY_DIM * d * 4) as u64)?;
    let grad_d = Buffer::device(&ctx, "bench/dD", (k * d * 4) as u64)?;
    let params = DecoderParams {
        w: &w,
        atoms: &atoms,
        atom_count: b.atoms,
    };
    let grads = || DecoderGrads {
        queries: Some(&grad_q),
        w: &grad_w,
        atoms: &grad_d,
    };
    let mut per_kernel = BTreeMap::new();

    let forward = time(&ctx, b.runs, &mut per_kernel, || {
        let mut rec = ctx.recorder()?;
        dec.record_forward(&mut rec, params, &queries, b.regions)?;
        rec.submit()?.wait()
    })?;
    let backward = time(&ctx, b.runs, &mut per_kernel, || {
        let mut rec = ctx.recorder()?;
        dec.record_backward(&mut rec, params, &queries, b.regions, &grad_out, grads())?;
        rec.submit()?.wait()
    })?;

    // One Stage II iteration: W and D only, from cached pooled queries.
    let feature = FeatureLoss::new(&ctx, b.regions, b.dim, weights)?;
    let trust = TrustRegion::new(&ctx, b.atoms, b.dim, weights)?;
    let adam_w = AdamGroup::new(
        &ctx,
        "W",
        QUERY_DIM as u32,
        b.dim,
        AdamHyper::new(0.01, 1e-8),
    )?;
    let adam_d = AdamGroup::new(&ctx, "D", b.atoms, b.dim, AdamHyper::new(0.01, 1e-8))?;
    let runs = (b.runs + 1) as f64;
    let (stage2, stage2_floor) = with_floor(&ctx, runs, || {
        time(&ctx, b.runs, &mut per_kernel, || {
            let mut rec = ctx.recorder()?;
            dec.record_forward(&mut rec, params, &queries, b.regions)?;
            feature.record(&mut rec, dec.output(), &targets, &row_weights, b.regions)?;
            let g = DecoderGrads {
                queries: None,
                w: &grad_w,
                atoms: &grad_d,
            };
            dec.record_backward(&mut rec, params, &queries, b.regions, feature.grad(), g)?;
            trust.record(&mut rec, &atoms, &anchor, &grad_d, b.atoms)?;
            adam_w.record_step(&mut rec, &w, &grad_w, QUERY_DIM as u32, None)?;
            adam_d.record_step(&mut rec, &atoms, &grad_d, b.atoms, None)?;
            rec.submit()?.wait()
        })
    })?;

    let ((kmeans_ms, kmeans_familiar_ms), kmeans_floor) = with_floor(&ctx, 2.0 * runs, || {
        kmeans_times(&ctx, &b, &mut rng, &mut per_kernel)
    })?;
    let (image_ms, ssim_ms) = image_loss_times(&ctx, &b, &mut rng, weights, &mut per_kernel)?;

    let report = Report {
        device: ctx.info().name.clone(),
        regions: b.regions,
        atoms: b.atoms,
        dim: b.dim,
        ssim_width: b.ssim_width,
        ssim_height: b.ssim_height,
        runs: b.runs,
        decode_forward_ms_median: forward,
        decode_backward_ms_median: backward,
        decode_gflops: decode_flops(n, k, d) / ((forward + backward) * 1e-3) * 1e-9,
        stage2_iteration_ms_median: stage2,
        kmeans_ms_median: kmeans_ms,
        kmeans_familiar_ms_median: kmeans_familiar_ms,
        ssim_forward_backward_ms_median: ssim_ms,
        image_loss_ms_median: image_ms,
        stage2_iteration_floor: stage2_floor,
        kmeans_floor,
        // Every measured run of every operation above, pooled by kernel.
        kernels: kernel_rows(per_kernel, b.runs),
    };
    print_report(&report);
    print_kernel_rows(&report.kernels);
    write_json(b.json.as_deref(), &report)
}
