//! `latentam bench raster`: forward and backward of the rasterizer on a
//! room-like scene (Gaussians spread over the walls, floor and ceiling of a
//! box room, cameras inside looking at them, as in a real map).
//!
//! Besides the times, it states how far they are from what the machine
//! could do: the blending work is counted exactly (with the f64 reference's
//! walk of every pixel, `latentam_reference::raster::blend_work`), turned into
//! arithmetic operations and bytes by [`CostModel`], and divided by the
//! machine's measured FMA rate and copy bandwidth (the probes of `bench
//! primitives`). The ratio of the measured time to that bound is what the
//! rasterizer's speed target is stated in.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Result;
use glam::DVec3;
use latentam_core::splat::{Camera, GaussianBuffers, HostGaussians, Rasterizer, QUERY_DIM};
use rand::{Rng, SeedableRng};
use serde::Serialize;

use super::common::{
    kernel_rows, measure_bandwidth, measure_fma_peak, median, print_kernel_rows, profiling_context,
    write_json, KernelRow, Row,
};

/// Settings of one raster benchmark.
pub struct RasterBench {
    pub width: u32,
    pub height: u32,
    pub gaussians: u64,
    pub views: u32,
    pub runs: usize,
    pub json: Option<PathBuf>,
}

#[derive(Serialize)]
struct Report {
    device: String,
    width: u32,
    height: u32,
    gaussians: u64,
    views: u32,
    runs: usize,
    visible: u64,
    intersections: u64,
    /// Σ over tiles of (list length × pixels): the (pixel, Gaussian) pairs
    /// blending may visit, an upper bound of the work.
    pixel_gaussian_pairs: u64,
    forward_ms_median: f64,
    backward_ms_median: f64,
    forward_wall_ms_median: f64,
    backward_wall_ms_median: f64,
    /// Whether the query channels' gradients stop at the queries (the
    /// default), which the backward cost depends on.
    detach_query_gradients: bool,
    work: Work,
    roofline: Roofline,
    kernels: Vec<KernelRow>,
}

/// The blending work of the batch, summed over its views.
#[derive(Serialize, Default)]
struct Work {
    /// (pixel, Gaussian) pairs the forward pass tests.
    tested_forward: u64,
    /// Pairs the backward pass tests (up to each pixel's last contributor).
    tested_backward: u64,
    /// Pairs blended (and differentiated).
    contributing: u64,
    /// Pixels of the batch.
    pixels: u64,
    /// (tile, list entry) pairs walked until every pixel of the tile is
    /// saturated: what kernels moving a whole tile in step walk.
    tile_entries_walked: u64,
    /// (tile, list entry) pairs up to each tile's last contributor.
    tile_entries_walked_backward: u64,
    /// (tile, list entry) pairs contributing to at least one pixel.
    tile_entries_contributing: u64,
}

/// The measured times against the machine's limits.
#[derive(Serialize)]
struct Roofline {
    /// Attainable arithmetic rate (FMA probe), GFLOP/s.
    machine_gflops: f64,
    /// Copy bandwidth, GB/s.
    machine_gbps: f64,
    forward_gflop: f64,
    backward_gflop: f64,
    forward_mb: f64,
    backward_mb: f64,
    /// max(operations / rate, bytes / bandwidth) of forward + backward.
    bound_ms: f64,
    /// Measured forward + backward GPU time (all kernels), median.
    measured_ms: f64,
    /// measured / bound.
    ratio: f64,
    /// Measured time per tested pair (forward + backward), ns.
    ns_per_tested_pair: f64,
}

/// Operations and bytes the blending passes cannot avoid, per unit of work.
/// Counted from the reference's math: an add, multiply, compare or min is
/// one operation, a fused multiply-add two, an exponential ten (range
/// reduction and a degree-5 polynomial, as vector libraries do it). The
/// projection, sorting and binning (a few per cent of the time) are left
/// out, which makes the bound tighter, never looser.
struct CostModel;

impl CostModel {
    /// Testing a pair: d = m − p (2), σ (9), e^(−σ) (10), α = min(o·v, 0.99)
    /// (2), the σ ≥ 0 and α ≥ 1/255 tests (2).
    const TEST: f64 = 25.0;
    /// Blending a contributor: T(1 − α) and its test (3), w = αT (1), w·f
    /// added to RGB, depth and the 32 query channels (36 FMA).
    const BLEND: f64 = 4.0 + 72.0;
    /// Differentiating a contributor with the query channels detached: w,
    /// 1/(1 − α), T update (5); running RGB-depth sum (4 FMA); ∂α from 4
    /// channels (26); ∂colour, ∂depth, ∂query = w·upstream (36); ∂σ, ∂conic,
    /// ∂mean, ∂opacity (14); adding the 43 gradients into the Gaussian's
    /// sums (43).
    const GRAD_DETACHED: f64 = 5.0 + 8.0 + 26.0 + 36.0 + 14.0 + 43.0;
    /// The 32 query channels' running sum (32 FMA) and their share of ∂α
    /// (6 per channel), when the query gradients reach opacity and geometry.
    const GRAD_QUERY: f64 = 64.0 + 192.0;
    /// Bytes per tile-list entry and pass: its pair index, projected splat
    /// (32), colour and query (140).
    const ENTRY_BYTES: f64 = 4.0 + 32.0 + 140.0;
    /// Backward, per tile-list entry: read-modify-write of the Gaussian's
    /// 42 gradient sums (35 per Gaussian, 7 per view and Gaussian).
    const ENTRY_GRAD_BYTES: f64 = 42.0 * 8.0;
    /// Forward output per pixel: RGB-depth, alpha, query, backward state.
    const PIXEL_OUT_BYTES: f64 = 16.0 + 4.0 + 128.0 + 8.0;
    /// Backward input per pixel: the forward outputs and their gradients.
    const PIXEL_GRAD_BYTES: f64 = Self::PIXEL_OUT_BYTES + 16.0 + 4.0 + 128.0;

    fn forward_ops(w: &Work) -> f64 {
        Self::TEST * w.tested_forward as f64 + Self::BLEND * w.contributing as f64
    }

    fn backward_ops(w: &Work, detach: bool) -> f64 {
        let per = Self::GRAD_DETACHED + if detach { 0.0 } else { Self::GRAD_QUERY };
        Self::TEST * w.tested_backward as f64 + per * w.contributing as f64
    }

    fn forward_bytes(w: &Work, entries: u64) -> f64 {
        Self::ENTRY_BYTES * entries as f64 + Self::PIXEL_OUT_BYTES * w.pixels as f64
    }

    fn backward_bytes(w: &Work, entries: u64) -> f64 {
        (Self::ENTRY_BYTES + Self::ENTRY_GRAD_BYTES) * entries as f64
            + Self::PIXEL_GRAD_BYTES * w.pixels as f64
    }
}

/// Counts the blending work of every view with the f64 reference.
fn blend_work(host: &HostGaussians, cams: &[Camera]) -> Work {
    let gs = latentam_reference::raster::Gaussian::all(host);
    let mut w = Work::default();
    for cam in cams {
        let v = latentam_reference::raster::blend_work(&gs, cam);
        w.tested_forward += v.tested;
        w.tested_backward += v.tested_backward;
        w.contributing += v.contributing;
        w.pixels += cam.pixels();
        w.tile_entries_walked += v.tile_entries_walked;
        w.tile_entries_walked_backward += v.tile_entries_walked_backward;
        w.tile_entries_contributing += v.tile_entries_contributing;
    }
    w
}

/// Gaussians on the far wall, floor, ceiling and side walls of a 4 x 2.4 x 4
/// m room (x right, y down, z forward), roughly one per `spacing` x
/// `spacing` patch, flat along the surface normal; the cameras stand at its
/// open side looking in, so most Gaussians are in view, as in the local
/// window around a mapping camera.
fn room_scene(n: u64, rng: &mut impl Rng) -> HostGaussians {
    let lo = DVec3::new(-2.0, -1.2, 0.0);
    let hi = DVec3::new(2.0, 1.2, 4.0);
    // (axis, coordinate) of each surface.
    let faces = [(2usize, hi.z), (1, hi.y), (1, lo.y), (0, lo.x), (0, hi.x)];
    let size = hi - lo;
    let areas: Vec<f64> = faces
        .iter()
        .map(|&(axis, _)| size.x * size.y * size.z / size[axis])
        .collect();
    let area: f64 = areas.iter().sum();
    let spacing = (area / n as f64).sqrt();
    let mut g = HostGaussians::zeros(n as usize);
    for i in 0..n as usize {
        // Faces picked in proportion to their area.
        let mut pick = rng.random_range(0.0..area);
        let mut f = 0;
        while f + 1 < faces.len() && pick >= areas[f] {
            pick -= areas[f];
            f += 1;
        }
        let (axis, at) = faces[f];
        let mut p = [0.0f64; 3];
        for (a, v) in p.iter_mut().enumerate() {
            *v = if a == axis {
                at + rng.random_range(-0.01..0.01)
            } else {
                rng.random_range(lo[a]..hi[a])
            };
        }
        g.means[i] = p.map(|v| v as f32);
        let mut ls = [(spacing * rng.random_range(0.4..0.8)).ln() as f32; 3];
        ls[axis] = (spacing * 0.1).ln() as f32;
        g.log_scales[i] = ls;
        // A small random tilt.
        g.quats[i] = [
            1.0,
            rng.random_range(-0.2..0.2),
            rng.random_range(-0.2..0.2),
            rng.random_range(-0.2..0.2),
        ];
        g.colors[i] = [0; 3].map(|_| rng.random_range(0.0..1.0));
        g.opacity_logits[i] = rng.random_range(1.0..4.0);
        g.queries[i] = [0; QUERY_DIM].map(|_| rng.random_range(-1.0..1.0));
    }
    g
}

/// Cameras near the room's open side looking in, a little apart, like the
/// keyframes of one batch.
fn cameras(b: &RasterBench, rng: &mut impl Rng) -> Vec<Camera> {
    (0..b.views)
        .map(|_| {
            let eye = DVec3::new(
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.6..-0.2),
            );
            let target = DVec3::new(
                rng.random_range(-0.8..0.8),
                rng.random_range(-0.4..0.4),
                4.0,
            );
            // About 60 degrees across, like common RGB-D cameras.
            let focal = 0.87 * b.width as f64;
            Camera::looking_at(eye, target, DVec3::NEG_Y, b.width, b.height, focal)
        })
        .collect()
}

/// GPU and wall times of every run (after a first, untimed one) of the
/// forward and the backward pass, and each kernel's GPU times.
struct Passes {
    fwd: Vec<f64>,
    bwd: Vec<f64>,
    fwd_wall: Vec<f64>,
    bwd_wall: Vec<f64>,
    per_kernel: BTreeMap<&'static str, Vec<f64>>,
}

/// Times `b.runs` forward and backward passes over the benchmark's views;
/// `upstream` holds the RGB-depth, alpha and query gradients fed back.
fn time_passes(
    ctx: &latentam_gpu::Context,
    raster: &mut Rasterizer,
    params: &GaussianBuffers,
    grads: &GaussianBuffers,
    b: &RasterBench,
    cams: &[Camera],
    upstream: &[Vec<f32>; 3],
) -> Result<Passes> {
    let mut fwd = Vec::new();
    let mut bwd = Vec::new();
    let mut fwd_wall = Vec::new();
    let mut bwd_wall = Vec::new();
    let mut per_kernel: BTreeMap<&'static str, Vec<f64>> = BTreeMap::new();
    let gpu_ms = |samples: &[latentam_gpu::Sample]| -> f64 {
        samples.iter().map(|s| s.duration_ns * 1e-6).sum()
    };
    let mut progress = latentam_cli::progress::Progress::new("bench raster", b.runs + 1);
    for run in 0..=b.runs {
        progress.set(run);
        // Forward (its view upload included: it is part of every render).
        ctx.profiler_reset();
        let t = std::time::Instant::now();
        raster.forward(params, b.gaussians, cams)?;
        let fw = t.elapsed().as_secs_f64() * 1e3;
        let mut samples = ctx.profiler_snapshot().samples().to_vec();
        let f = gpu_ms(&samples);

        let g = raster.image_grads()?;
        ctx.upload(&g.rgbd, 0, &upstream[0])?;
        ctx.upload(&g.alpha, 0, &upstream[1])?;
        ctx.upload(g.query()?, 0, &upstream[2])?;
        ctx.profiler_reset();
        let t = std::time::Instant::now();
        raster.backward(params, grads)?;
        let bw = t.elapsed().as_secs_f64() * 1e3;
        let backward_samples = ctx.profiler_snapshot().samples().to_vec();
        let bk = gpu_ms(&backward_samples);
        samples.extend(backward_samples);
        if run > 0 {
            fwd.push(f);
            bwd.push(bk);
            fwd_wall.push(fw);
            bwd_wall.push(bw);
            for s in samples {
                per_kernel
                    .entry(s.name)
                    .or_default()
                    .push(s.duration_ns * 1e-6);
            }
        }
    }
    progress.set(b.runs + 1);
    Ok(Passes {
        fwd,
        bwd,
        fwd_wall,
        bwd_wall,
        per_kernel,
    })
}

pub fn run(b: RasterBench) -> Result<()> {
    let ctx = profiling_context()?;
    eprintln!(
        "benchmarking the rasterizer on {}: {} view(s) of {}x{}, {} Gaussians, {} runs...",
        ctx.info().name,
        b.views,
        b.width,
        b.height,
        b.gaussians,
        b.runs
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let host = room_scene(b.gaussians, &mut rng);
    let cams = cameras(&b, &mut rng);
    let params = GaussianBuffers::new(&ctx, "bench_gaussians", b.gaussians)?;
    params.upload(&ctx, 0, &host)?;
    let grads = GaussianBuffers::new(&ctx, "bench_grads", b.gaussians)?;
    let mut raster = Rasterizer::new(&ctx);

    // Upstream gradients: any values exercise the same work.
    raster.forward(&params, b.gaussians, &cams)?;
    let pixels = raster.layout().pixels as usize;
    let up_rgbd: Vec<f32> = (0..pixels * 4)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let up_alpha: Vec<f32> = (0..pixels).map(|_| rng.random_range(-1.0..1.0)).collect();
    let up_query: Vec<f32> = (0..pixels * QUERY_DIM)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();

    let upstream = [up_rgbd, up_alpha, up_query];
    let Passes {
        fwd,
        bwd,
        fwd_wall,
        bwd_wall,
        per_kernel,
    } = time_passes(&ctx, &mut raster, &params, &grads, &b, &cams, &upstream)?;

    let stats = raster.stats();
    // Work bound: every pixel of a tile walks (at most) the tile's list.
    let pairs = pixel_gaussian_pairs(&raster)?;

    eprintln!("counting the blending work and measuring the machine's limits...");
    let work = blend_work(&host, &cams);
    let copy = measure_bandwidth(&ctx, 64 << 20, b.runs)?;
    let fma = measure_fma_peak(&ctx, 4096, b.runs)?;
    let detach = raster.settings.detach_query_gradients;
    let measured_ms = median(&fwd) + median(&bwd);
    let roofline = Roofline::of(&work, stats.intersections, &copy, &fma, detach, measured_ms);

    let kernels = kernel_rows(per_kernel, b.runs);
    let report = Report {
        device: ctx.info().name.clone(),
        width: b.width,
        height: b.height,
        gaussians: b.gaussians,
        views: b.views,
        runs: b.runs,
        visible: stats.visible,
        intersections: stats.intersections,
        pixel_gaussian_pairs: pairs,
        forward_ms_median: median(&fwd),
        backward_ms_median: median(&bwd),
        forward_wall_ms_median: median(&fwd_wall),
        backward_wall_ms_median: median(&bwd_wall),
        detach_query_gradients: detach,
        work,
        roofline,
        kernels,
    };

    print_report(&report);
    print_kernel_rows(&report.kernels);
    write_json(b.json.as_deref(), &report)?;
    Ok(())
}

impl Roofline {
    /// The bound of forward + backward on this machine (`copy` bandwidth,
    /// `fma` rate) for `work` over `intersections` tile entries, against
    /// the `measured_ms` GPU time.
    fn of(
        work: &Work,
        intersections: u64,
        copy: &Row,
        fma: &Row,
        detach: bool,
        measured_ms: f64,
    ) -> Roofline {
        let (f_ops, b_ops) = (
            CostModel::forward_ops(work),
            CostModel::backward_ops(work, detach),
        );
        let (f_bytes, b_bytes) = (
            CostModel::forward_bytes(work, intersections),
            CostModel::backward_bytes(work, intersections),
        );
        let bound_ms = ((f_ops + b_ops) / (fma.throughput * 1e9))
            .max((f_bytes + b_bytes) / (copy.throughput * 1e9))
            * 1e3;
        Roofline {
            machine_gflops: fma.throughput,
            machine_gbps: copy.throughput,
            forward_gflop: f_ops * 1e-9,
            backward_gflop: b_ops * 1e-9,
            forward_mb: f_bytes * 1e-6,
            backward_mb: b_bytes * 1e-6,
            bound_ms,
            measured_ms,
            ratio: measured_ms / bound_ms,
            ns_per_tested_pair: measured_ms * 1e6
                / (work.tested_forward + work.tested_backward).max(1) as f64,
        }
    }
}

/// The report's figures on the terminal (the kernel table apart).
fn print_report(r: &Report) {
    println!(
        "device: {}\n{} view(s) {}x{}, {} Gaussians: {} visible pairs, {} tile intersections, \
         {} pixel-Gaussian pairs",
        r.device,
        r.views,
        r.width,
        r.height,
        r.gaussians,
        r.visible,
        r.intersections,
        r.pixel_gaussian_pairs
    );
    println!(
        "forward  {:>10.3} ms GPU (median; wall {:.3} ms)\nbackward {:>10.3} ms GPU (median; wall \
         {:.3} ms)",
        r.forward_ms_median,
        r.forward_wall_ms_median,
        r.backward_ms_median,
        r.backward_wall_ms_median
    );
    let (w, rl) = (&r.work, &r.roofline);
    println!(
        "blending work: {} pairs tested forward, {} backward, {} contributing ({:.1} per pixel)",
        w.tested_forward,
        w.tested_backward,
        w.contributing,
        w.contributing as f64 / w.pixels.max(1) as f64
    );
    println!(
        "tile-list entries: {} walked forward, {} backward, {} contributing to a pixel",
        w.tile_entries_walked, w.tile_entries_walked_backward, w.tile_entries_contributing
    );
    println!(
        "machine: {:.1} GFLOP/s (FMA probe), {:.1} GB/s (copy); needed: forward {:.3} GFLOP \
         {:.1} MB, backward {:.3} GFLOP {:.1} MB\nbound {:.2} ms; measured {:.2} ms = {:.1}x the \
         bound ({:.1} ns per tested pair)",
        rl.machine_gflops,
        rl.machine_gbps,
        rl.forward_gflop,
        rl.forward_mb,
        rl.backward_gflop,
        rl.backward_mb,
        rl.bound_ms,
        rl.measured_ms,
        rl.ratio,
        rl.ns_per_tested_pair
    );
}

/// Σ over tiles of list length × pixels in the tile, from the last forward.
fn pixel_gaussian_pairs(raster: &Rasterizer) -> Result<u64> {
    let lens = raster.tile_list_lengths()?;
    let layout = raster.layout();
    let mut total = 0u64;
    for v in &layout.views {
        for ty in 0..v.tiles_y {
            for tx in 0..v.tiles_x {
                let w = (v.width - tx * 16).min(16) as u64;
                let h = (v.height - ty * 16).min(16) as u64;
                let len = lens[(v.first_tile + ty * v.tiles_x + tx) as usize] as u64;
                total += len * w * h;
            }
        }
    }
    Ok(total)
}
