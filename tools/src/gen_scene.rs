//! `latentam gen-scene`: the demo scene as an MCAP log.

use std::path::PathBuf;

use clap::ValueEnum;
use latentam::frames::Dtype;
use latentam::logs::Compression;
use latentam_cli::progress::Progress;
use latentam_scene::{generate, spread_for_cosine, SceneConfig};

/// Chunk compression of written logs.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum CompressionArg {
    /// zstd: smallest files.
    Zstd,
    /// lz4: fastest to read.
    Lz4,
    /// No compression.
    None,
}

impl From<CompressionArg> for Compression {
    fn from(c: CompressionArg) -> Self {
        match c {
            CompressionArg::Zstd => Compression::Zstd,
            CompressionArg::Lz4 => Compression::Lz4,
            CompressionArg::None => Compression::None,
        }
    }
}

/// Element type of written embeddings.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum DtypeArg {
    /// IEEE half precision.
    F16,
    /// IEEE single precision.
    F32,
}

impl From<DtypeArg> for Dtype {
    fn from(d: DtypeArg) -> Self {
        match d {
            DtypeArg::F16 => Dtype::F16,
            DtypeArg::F32 => Dtype::F32,
        }
    }
}

#[derive(clap::Args)]
pub struct Args {
    /// Output MCAP file (written beside it under a partial name of its own,
    /// then renamed).
    #[arg(short, long)]
    out: PathBuf,
    /// Number of frames along the trajectory (the path is the same length
    /// whatever the count; more frames = smaller steps).
    #[arg(long, default_value_t = 300)]
    frames: usize,
    /// Image width in pixels.
    #[arg(long, default_value_t = 160)]
    width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 120)]
    height: u32,
    /// Dimension of the synthetic region embeddings.
    #[arg(long, default_value_t = 512)]
    dim: usize,
    /// Element type of the embeddings.
    #[arg(long, value_enum, default_value_t = DtypeArg::F16)]
    dtype: DtypeArg,
    /// Seed of the synthetic embeddings (same seed, same log).
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Frame rate: stamps are 1/FPS seconds apart.
    #[arg(long, default_value_t = 10.0)]
    fps: f64,
    /// Chunk compression.
    #[arg(long, value_enum, default_value_t = CompressionArg::Zstd)]
    compression: CompressionArg,
    /// Walk the path this many times, alternately forwards and backwards
    /// (the frames are spread over all laps).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    laps: u64,
    /// Cosine between a region's embedding in one view and its object's
    /// (fresh noise per view, as a vision-language model's embeddings of
    /// one thing vary across views); 1 gives every view the same vector.
    #[arg(long, default_value_t = 0.85, value_parser = unit_interval)]
    view_cosine: f32,
    /// Probability that a pixel on a mask's boundary is mislabelled (left
    /// out of its mask or given to the neighbouring mask, half each), as
    /// a segmenter's masks miss and spill; 0 gives exact masks.
    #[arg(long, default_value_t = 0.5, value_parser = probability)]
    mask_noise: f32,
    /// Auto-exposure: the camera's gain swings between exp(-S) and exp(S)
    /// over the run (one and a half slow swings), as a camera's does
    /// between bright and dark parts of a room; 0 keeps it constant.
    #[arg(long, default_value_t = 0.0, value_parser = exposure_swing)]
    exposure_swing: f32,
    /// Instead of the demo's two rooms, a building of N rooms (2 to 1000)
    /// in two rows along corridors, joined at each end by a hall; the path
    /// walks through every room once and returns to its start (about 12 m
    /// of path a room: 254 m for N = 20). For long runs whose map outgrows
    /// memory; give enough frames for the walk (the demo's pace is about
    /// 10 a metre: 300 frames along its 31 m).
    #[arg(long, value_parser = clap::value_parser!(u64).range(latentam_scene::MIN_ROOMS as u64..=latentam_scene::MAX_ROOMS as u64))]
    rooms: Option<u64>,
}

fn exposure_swing(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        Ok(v) => Err(format!("{v} is outside [0, 1]")),
        Err(e) => Err(e.to_string()),
    }
}

fn unit_interval(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(v) if v > 0.0 && v <= 1.0 => Ok(v),
        Ok(v) => Err(format!("{v} is outside (0, 1]")),
        Err(e) => Err(e.to_string()),
    }
}

fn probability(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        Ok(v) => Err(format!("{v} is outside [0, 1]")),
        Err(e) => Err(e.to_string()),
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = SceneConfig {
        frames: args.frames,
        width: args.width,
        height: args.height,
        dim: args.dim,
        dtype: args.dtype.into(),
        seed: args.seed,
        fps: args.fps,
        compression: args.compression.into(),
        laps: args.laps as usize,
        view_spread: spread_for_cosine(args.view_cosine),
        mask_noise: args.mask_noise,
        exposure_swing: args.exposure_swing,
        rooms: args.rooms.map(|n| n as usize),
        ..SceneConfig::default()
    };
    let mut progress = Progress::new("gen-scene", config.frames);
    let summary = generate(&config, &args.out, |done| progress.set(done))?;
    let bytes = std::fs::metadata(&args.out).map(|m| m.len()).unwrap_or(0);
    println!(
        "wrote {}: {} frames of {}×{} along {:.0} m, {} regions ({} objects, {} classes), {:.1} MB",
        args.out.display(),
        summary.frames,
        config.width,
        config.height,
        summary.path_metres,
        summary.regions,
        summary.objects,
        summary.classes,
        bytes as f64 / 1e6
    );
    Ok(())
}
