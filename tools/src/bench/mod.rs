//! `latentam bench ...`: benchmarks that print a table and write JSON.
//! Times are GPU time from timestamp queries (the sum of the operation's
//! commands), median over the measured runs after one warm-up run (lavapipe
//! compiles a pipeline on its first dispatch).
//!
//! Unlike the rest of the tool, which uses the `latentam` façade alone,
//! the benchmarks reach into the lower crates (`latentam-core`,
//! `latentam-gpu`, `latentam-io`, `latentam-base`, the CPU reference and
//! the shaders): they measure the layers themselves, below what the
//! façade exports.

mod common;
mod decode;
mod ingest;
mod latent;
mod live;
mod map;
mod primitives;
mod query;
mod raster;
mod soak;

use std::path::PathBuf;

use anyhow::Result;
use clap::Subcommand;

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
        /// Also state the floor per keyframe on a GPU of this peak FP32
        /// rate (TFLOPS; a fused multiply-add counts two), beside the RTX
        /// 4090 and Jetson AGX Orin models. Needs --gpu-gbs.
        #[arg(long, requires = "gpu_gbs", value_parser = positive_f64)]
        gpu_tflops: Option<f64>,
        /// That GPU's memory bandwidth, GB/s (also taken for its host
        /// link). Needs --gpu-tflops.
        #[arg(long, requires = "gpu_tflops", value_parser = positive_f64)]
        gpu_gbs: Option<f64>,
    },
    /// Long run on the demo scene walked lap after lap: GPU and CPU bytes,
    /// Gaussians, kept keyframes and live Vulkan objects per keyframe, and
    /// per lap.
    Soak(soak::Args),
    /// The live handle under a camera's rate: a generated 640×480 scene
    /// submitted at 30 Hz, alone and with relevance queries at 2 Hz (on the
    /// live map and on a 100 000-Gaussian snapshot with K = 2000, d_f =
    /// 768) and renders: submit, query and render latencies, mapping
    /// throughput with and without queries, drops, time to ready on a new
    /// machine (empty driver and pipeline caches) and again with warm ones,
    /// the first keyframe against the next five, and abort latency.
    Live(live::Args),
    /// The per-pixel evaluation of one view (every pixel's query decoded,
    /// its cosine to its region's target and its class among a
    /// vocabulary) on the device and on the CPU, on the same generated
    /// inputs: time per view, atoms a pixel's embedding needs, per-kernel
    /// breakdown.
    Decode(decode::Args),
    /// Relevance of every Gaussian of a saved map to an embedding, query
    /// after query, with the map loaded under a host budget: the first
    /// query (which builds the relevance index, reading blocks past the
    /// budget from disk), p50 and p99 latency of the others, peak RSS.
    Query(query::Args),
}

pub fn run(which: Which) -> Result<()> {
    match which {
        Which::Primitives { json, runs, quick } => primitives::run(json, runs as usize, quick),
        Which::Raster {
            width,
            height,
            gaussians,
            views,
            runs,
            json,
        } => raster::run(raster::RasterBench {
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
        } => latent::run(latent::LatentBench {
            regions,
            atoms,
            dim,
            ssim_width,
            ssim_height,
            runs: runs as usize,
            json,
        }),
        Which::Soak(args) => soak::run_bench(args),
        Which::Live(args) => live::run(args),
        Which::Decode(args) => decode::run(args),
        Which::Query(args) => query::run(args),
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
            gpu_tflops,
            gpu_gbs,
        } => map::run(map::MapBench {
            frames: frames as usize,
            width,
            height,
            dim: dim as usize,
            log,
            config,
            budget,
            eval_keyframes: eval_keyframes as usize,
            json,
            gpu: gpu_tflops
                .zip(gpu_gbs)
                .map(|(tflops, gbs)| map::custom_gpu(tflops, gbs)),
        }),
        Which::Ingest {
            width,
            height,
            regions,
            dim,
            frames,
            json,
        } => ingest::run(ingest::IngestBench {
            width,
            height,
            regions,
            dim,
            frames: frames as usize,
            json,
        }),
    }
}

/// A finite number above 0.
fn positive_f64(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("`{s}` is not a number above 0")),
    }
}
