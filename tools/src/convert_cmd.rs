//! `latentam convert`: dataset folders to MCAP logs.

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::ValueEnum;
use latentam_cli::convert::features::FeatureDir;
use latentam_cli::convert::oracle::Oracle;
use latentam_cli::convert::{
    convert, datasets, ConvertOptions, DepthCamera, EmbeddingSource, Registration,
};
use latentam_cli::progress::Progress;

use crate::gen_scene::{CompressionArg, DtypeArg};

/// Dataset folder layouts.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Kind {
    /// TUM RGB-D (rgb.txt, depth.txt, groundtruth.txt).
    Tum,
    /// Microsoft 7-Scenes (frame-XXXXXX.{color.jpg,depth.png,pose.txt}).
    #[value(name = "7scenes")]
    SevenScenes,
    /// Replica in the NICE-SLAM layout (results/, traj.txt, cam_params.json).
    Replica,
}

#[derive(clap::Args)]
pub struct Args {
    /// Layout of the dataset folder.
    #[arg(value_enum)]
    kind: Kind,
    /// The dataset folder.
    dir: PathBuf,
    /// Output MCAP file (written beside it under a partial name of its own,
    /// then renamed).
    #[arg(short, long)]
    out: PathBuf,
    /// Folder of per-frame feature files (`S.safetensors`, or `.npy`; see
    /// the "Embedding files" section of docs/input-logs.md).
    #[arg(long, conflicts_with = "oracle_labels")]
    features: Option<PathBuf>,
    /// Embedding model id for the feature files (overrides their metadata;
    /// required for .npy files without a model.txt).
    #[arg(long, requires = "features")]
    model: Option<String>,
    /// Folder of per-frame class-id images for ORACLE embeddings
    /// (evaluation only): each class present becomes a region whose
    /// target is its class vector.
    #[arg(long, requires = "class_vectors")]
    oracle_labels: Option<PathBuf>,
    /// Class vectors for --oracle-labels: .npy [C, D] or .safetensors with
    /// `vectors` (and optional `names`, `model` metadata).
    #[arg(long, requires = "oracle_labels")]
    class_vectors: Option<PathBuf>,
    /// The colour camera's intrinsics `fx,fy,cx,cy` in pixels, instead of
    /// the dataset's.
    #[arg(long, value_delimiter = ',', num_args = 4)]
    intrinsics: Option<Vec<f64>>,
    /// Depth comes from a second lens with these intrinsics `fx,fy,cx,cy`:
    /// it is re-projected into the colour camera (nearest surface wins).
    /// 7-Scenes does this by default with its measured colour lens.
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 4,
        conflicts_with = "no_registration"
    )]
    depth_intrinsics: Option<Vec<f64>>,
    /// With --depth-intrinsics: the depth lens's origin `x,y,z` in metres
    /// in the colour camera's optical frame (x right, y down, z forward;
    /// the lenses are taken as parallel).
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 3,
        requires = "depth_intrinsics",
        allow_hyphen_values = true
    )]
    depth_offset: Option<Vec<f64>>,
    /// With --depth-intrinsics: the dataset's poses are the depth lens's
    /// (they are moved to the colour lens).
    #[arg(long, requires = "depth_intrinsics")]
    depth_poses: bool,
    /// Keep depth as recorded, with the depth camera as the camera (for
    /// datasets registered by default, 7-Scenes).
    #[arg(long)]
    no_registration: bool,
    /// Write depth from a second lens as a driver records a raw stream: in
    /// its own optical frame, with its camera info on
    /// /camera/depth/camera_info and the transform between the lenses on
    /// /tf_static; `latentam map` registers it while reading.
    #[arg(long, conflicts_with = "no_registration")]
    raw_depth: bool,
    /// Depth units per metre of the dataset's PNGs, instead of the layout's
    /// default (7-Scenes 1000, TUM 5000, Replica 6553.5).
    #[arg(long)]
    depth_units_per_metre: Option<f64>,
    /// Frame rate given to datasets without time stamps (7-Scenes, Replica).
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// Convert only the first N frames.
    #[arg(long)]
    max_frames: Option<usize>,
    /// Element type of written embeddings.
    #[arg(long, value_enum, default_value_t = DtypeArg::F16)]
    dtype: DtypeArg,
    /// Chunk compression.
    #[arg(long, value_enum, default_value_t = CompressionArg::Zstd)]
    compression: CompressionArg,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // Stamps are index / fps: within this range they stay distinct and
    // within i64 for any dataset this tool reads.
    let (min, max) = (latentam_scene::MIN_FPS, latentam_scene::MAX_FPS);
    if !(min..=max).contains(&args.fps) {
        bail!(
            "--fps must be from {min} to {max} frames per second, got {:?}",
            args.fps
        );
    }
    let dataset = match args.kind {
        Kind::Tum => datasets::tum(&args.dir),
        Kind::SevenScenes => datasets::seven_scenes(&args.dir, args.fps),
        Kind::Replica => datasets::replica(&args.dir, args.fps),
    }
    .with_context(|| format!("reading {}", args.dir.display()))?;
    let embeddings = match (&args.features, &args.oracle_labels, &args.class_vectors) {
        (Some(dir), _, _) => EmbeddingSource::Features(FeatureDir::new(dir, args.model.clone())?),
        (None, Some(labels), Some(vectors)) => {
            EmbeddingSource::Oracle(Oracle::new(labels, vectors)?)
        }
        _ => EmbeddingSource::None,
    };
    let options = ConvertOptions {
        embeddings,
        intrinsics: args.intrinsics.as_ref().map(|v| [v[0], v[1], v[2], v[3]]),
        registration: match (&args.depth_intrinsics, args.no_registration) {
            (Some(k), _) => Registration::Given(DepthCamera {
                intrinsics: [k[0], k[1], k[2], k[3]],
                translation: args
                    .depth_offset
                    .as_ref()
                    .map_or(glam::DVec3::ZERO, |t| glam::DVec3::new(t[0], t[1], t[2])),
                poses_are_depth: args.depth_poses,
            }),
            (None, true) => Registration::Off,
            (None, false) => Registration::Dataset,
        },
        raw_depth: args.raw_depth,
        depth_units_per_metre: args.depth_units_per_metre,
        dtype: args.dtype.into(),
        compression: args.compression.into(),
        max_frames: args.max_frames,
        kind: args
            .kind
            .to_possible_value()
            .map_or_else(String::new, |v| v.get_name().to_string()),
        source: args.dir.clone(),
    };
    let total = args
        .max_frames
        .unwrap_or(usize::MAX)
        .min(dataset.color.len());
    let mut progress = Progress::new("convert", total);
    let summary = convert(dataset, &options, &args.out, |done, _| progress.set(done))?;
    for note in &summary.notes {
        eprintln!("note: {note}");
    }
    if !summary.skipped.is_empty() {
        eprintln!("{} frames left out:", summary.skipped.len());
        for s in summary.skipped.iter().take(10) {
            eprintln!("  {s}");
        }
        if summary.skipped.len() > 10 {
            eprintln!("  … and {} more", summary.skipped.len() - 10);
        }
    }
    if summary.without_embeddings > 0 {
        eprintln!(
            "warning: {} frames had no embedding file and were written without embeddings",
            summary.without_embeddings
        );
    }
    println!(
        "wrote {}: {} frames, {} depth images, {} poses, {} frames with embeddings",
        args.out.display(),
        summary.frames,
        summary.depth,
        summary.poses,
        summary.with_embeddings
    );
    Ok(())
}
