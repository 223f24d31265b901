//! `latentam bench decode`: the paper's per-pixel evaluation of one view
//! (every pixel's rendered query decoded, its cosine to its region's
//! target and its class among the vocabulary), on the device
//! ([`pixel_metrics_on_device`]) and on the CPU ([`pixel_metrics`], the
//! factorised reference), on the same inputs in the same run.
//!
//! The inputs are generated: atoms, targets and texts are unit vectors
//! clustered around a few directions like real region embeddings, the
//! regions a grid over the image, each region's pixels rendering one
//! query with a little noise.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use clap::Args as ClapArgs;
use latentam_core::latent::{DevicePixelDecoder, FactorisedDecoder};
use latentam_core::mapper::pixel_metrics::{pixel_metrics, pixel_metrics_on_device, PixelInputs};
use latentam_core::splat::QUERY_DIM;
use latentam_gpu::Sample;
use rand::{Rng, SeedableRng};
use serde::Serialize;

use super::common::{kernel_rows, median, print_kernel_rows, profiling_context, write_json};

/// Settings of `latentam bench decode`.
#[derive(ClapArgs)]
pub struct Args {
    /// Image width in pixels.
    #[arg(long, default_value_t = 640, value_parser = clap::value_parser!(u32).range(1..=8192))]
    width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 480, value_parser = clap::value_parser!(u32).range(1..=8192))]
    height: u32,
    /// Dictionary atoms (K).
    #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u32).range(1..=65_536))]
    atoms: u32,
    /// Embedding dimension (d_f).
    #[arg(long, default_value_t = 768, value_parser = clap::value_parser!(u32).range(1..=16_384))]
    dim: u32,
    /// Regions of the view (a grid), each with a target embedding.
    #[arg(long, default_value_t = 48, value_parser = clap::value_parser!(u32).range(1..=65_535))]
    regions: u32,
    /// Vocabulary words the pixels are classified among.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=4096))]
    texts: u32,
    /// Measured runs on the device (after one warm-up run); at least 3.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(3..))]
    runs: u32,
    /// Pixels the CPU decodes (every n-th pixel and row, n chosen to reach
    /// about this many); its time is scaled to the whole view. 0: all.
    #[arg(long, default_value_t = 20_000)]
    host_pixels: u64,
    /// Write the results as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Serialize)]
struct Report {
    device: String,
    width: u32,
    height: u32,
    atoms: u32,
    dim: u32,
    regions: u32,
    texts: u32,
    runs: u32,
    /// Wall time of the device path for the whole view, median.
    device_ms_median: f64,
    /// GPU time of the same, median (sum of its kernels and copies).
    device_gpu_ms_median: f64,
    /// CPU time for the whole view: measured on `host_pixels_measured`
    /// pixels (every `host_stride`-th pixel and row) and scaled.
    host_ms_estimated: f64,
    host_pixels_measured: u64,
    host_stride: usize,
    /// Multiply-adds a pixel on the device: 32 K + K d_f + (texts + 2) d_f.
    device_multiply_adds_per_pixel: f64,
    /// Largest difference in the mean cosine loss, device against CPU, on
    /// the CPU's pixels.
    cosine_loss_difference: f64,
    kernels: Vec<super::common::KernelRow>,
}

/// The generated view and map.
struct Scene {
    w: Vec<f32>,
    atoms: Vec<f32>,
    queries: Vec<[f32; QUERY_DIM]>,
    region: Vec<u32>,
    targets: Vec<f32>,
    truth: Vec<u16>,
    ids: Vec<u16>,
    texts: Vec<f32>,
}

fn scene(a: &Args, rng: &mut impl Rng) -> Scene {
    let (width, height) = (a.width as usize, a.height as usize);
    let dim = a.dim as usize;
    // Clustered like real region embeddings, as `bench latent` makes them.
    let centres = super::latent::directions(dim, rng);
    let atoms = super::latent::rows_around(&centres, a.atoms as usize, rng);
    let targets = super::latent::rows_around(&centres, a.regions as usize, rng);
    let texts = super::latent::rows_around(&centres, a.texts as usize, rng);
    let w: Vec<f32> = (0..QUERY_DIM * dim)
        .map(|_| rng.random_range(-0.5..0.5))
        .collect();
    // Regions: a grid of about `regions` cells.
    let cols = (a.regions as f64).sqrt().ceil() as usize;
    let rows = (a.regions as usize).div_ceil(cols);
    let codes: Vec<[f32; QUERY_DIM]> = (0..a.regions)
        .map(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)))
        .collect();
    let mut queries = Vec::with_capacity(width * height);
    let mut region = Vec::with_capacity(width * height);
    for y in 0..height {
        for x in 0..width {
            let cell = (y * rows / height) * cols + x * cols / width;
            let r = cell.min(a.regions as usize - 1);
            let c = &codes[r];
            queries.push(std::array::from_fn(|i| {
                c[i] + rng.random_range(-0.05..0.05)
            }));
            region.push(r as u32);
        }
    }
    let truth = region.iter().map(|&r| (r % a.texts) as u16 + 1).collect();
    Scene {
        w,
        atoms,
        queries,
        region,
        targets,
        truth,
        ids: (1..=a.texts as u16).collect(),
        texts,
    }
}

pub fn run(a: Args) -> Result<()> {
    let ctx = profiling_context()?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let s = scene(&a, &mut rng);
    let (k, dim) = (a.atoms, a.dim);
    let w = ctx.upload_new("bench/w", &s.w)?;
    let atoms = ctx.upload_new("bench/atoms", &s.atoms)?;
    let mut device = DevicePixelDecoder::new(&ctx, &w, &atoms, k, dim, 0.05, 1e-6)?;
    let inputs = |stride: usize| PixelInputs {
        width: a.width as usize,
        height: a.height as usize,
        queries: &s.queries,
        region: &s.region,
        targets: &s.targets,
        truth: &s.truth,
        vocabulary: Some((&s.ids, &s.texts)),
        stride,
    };
    let pixels = (a.width as u64 * a.height as u64) as f64;
    let mut progress = latentam_cli::progress::Progress::new("bench decode", a.runs as usize + 2);
    let (mut wall, mut gpu) = (Vec::new(), Vec::new());
    let mut per_kernel: BTreeMap<&'static str, Vec<f64>> = BTreeMap::new();
    for run in 0..=a.runs as usize {
        progress.set(run);
        ctx.profiler_reset();
        let t = Instant::now();
        pixel_metrics_on_device(&ctx, &mut device, &inputs(1))?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let samples: Vec<Sample> = ctx.profiler_snapshot().samples().to_vec();
        if run > 0 {
            wall.push(ms);
            gpu.push(samples.iter().map(|x| x.duration_ns * 1e-6).sum());
            for x in samples {
                per_kernel
                    .entry(x.name)
                    .or_default()
                    .push(x.duration_ns * 1e-6);
            }
        }
    }
    // The CPU on a strided subset, scaled to the view.
    progress.set(a.runs as usize + 1);
    let stride = if a.host_pixels == 0 {
        1
    } else {
        ((pixels / a.host_pixels as f64).sqrt().floor() as usize).max(1)
    };
    let host = FactorisedDecoder::new(&s.w, &s.atoms, dim as usize, 0.05, 1e-6)?;
    let t = Instant::now();
    let host_m = pixel_metrics(&host, &inputs(stride))?;
    let host_ms = t.elapsed().as_secs_f64() * 1e3;
    let measured = a.height.div_ceil(stride as u32) as u64 * a.width.div_ceil(stride as u32) as u64;
    let device_m = pixel_metrics_on_device(&ctx, &mut device, &inputs(stride))?;
    progress.set(a.runs as usize + 2);
    let difference =
        (host_m.cosine_loss().unwrap_or(0.0) - device_m.cosine_loss().unwrap_or(0.0)).abs();
    let report = Report {
        device: ctx.info().name.clone(),
        width: a.width,
        height: a.height,
        atoms: k,
        dim,
        regions: a.regions,
        texts: a.texts,
        runs: a.runs,
        device_ms_median: median(&wall),
        device_gpu_ms_median: median(&gpu),
        host_ms_estimated: host_ms * pixels / measured as f64,
        host_pixels_measured: measured,
        host_stride: stride,
        device_multiply_adds_per_pixel: QUERY_DIM as f64 * k as f64
            + (k as f64 + a.texts as f64 + 2.0) * dim as f64,
        cosine_loss_difference: difference,
        kernels: kernel_rows(per_kernel, a.runs as usize),
    };
    println!(
        "per-pixel decoding of a {}x{} view, K = {k}, d_f = {dim}, {} regions, {} texts on {}",
        a.width, a.height, a.regions, a.texts, report.device
    );
    println!(
        "  device: {:.0} ms (GPU {:.0} ms), {:.0} multiply-adds a pixel",
        report.device_ms_median, report.device_gpu_ms_median, report.device_multiply_adds_per_pixel
    );
    println!(
        "  CPU:    {:.0} ms (measured on {measured} pixels, one pixel in each {stride}×{stride} block)",
        report.host_ms_estimated
    );
    println!("  mean cosine loss, device - CPU: {difference:.2e}");
    print_kernel_rows(&report.kernels);
    write_json(a.json.as_deref(), &report)
}
