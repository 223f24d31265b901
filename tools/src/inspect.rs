//! `latentam inspect`: what a log holds and what the engine makes of it.

use std::path::PathBuf;

use latentam::io::{AssemblyConfig, McapFrames, McapLog, PoseSource, Topics};

#[derive(clap::Args)]
pub struct Args {
    /// An MCAP file or a rosbag2 directory of split files.
    log: PathBuf,
    /// Pose topic (PoseStamped or Odometry); ignored with --tf-world.
    #[arg(long, default_value = "/camera/pose")]
    pose_topic: String,
    /// Take poses from /tf + /tf_static, chained from this world frame to
    /// the colour image's frame.
    #[arg(long)]
    tf_world: Option<String>,
    /// Pairing tolerance between colour and depth/embedding stamps, ms.
    #[arg(long, default_value_t = 20.0)]
    tolerance_ms: f64,
    /// Metres per unit of 16-bit depth.
    #[arg(long, default_value_t = 0.001)]
    depth_scale: f32,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let log = McapLog::open(&args.log)?;
    if !args.json {
        println!("{}:", args.log.display());
        for (file, why) in log.unindexed_files() {
            println!("  warning: {}: {why}", file.display());
        }
        for c in log.channels() {
            let n = log
                .message_count(&c.topic)
                .map_or("?".into(), |n| n.to_string());
            println!("  {:<32} {:>7} × {}", c.topic, n, c.schema_name);
        }
        for (name, values) in log.metadata()? {
            for (k, v) in values {
                println!("  metadata {name}.{k}: {v}");
            }
        }
    }
    let pose = match args.tf_world {
        Some(world_frame) => PoseSource::Tf {
            world_frame,
            camera_frame: None,
        },
        None => PoseSource::Topic(args.pose_topic),
    };
    let config = AssemblyConfig {
        topics: Topics {
            pose,
            ..Topics::default()
        },
        tolerance_ns: (args.tolerance_ms * 1e6).round() as i64,
        depth_metres_per_unit: args.depth_scale,
        ..AssemblyConfig::default()
    };
    let mut frames = McapFrames::from_log(log, config)?;
    let mut first_error = None;
    let mut sizes = None;
    for f in &mut frames {
        match f {
            Ok(f) => sizes = sizes.or(Some((f.color.width, f.color.height))),
            Err(e) => {
                first_error.get_or_insert_with(|| e.to_string());
            }
        }
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(frames.report())?);
    } else {
        print!("{}", frames.report());
        if let Some((w, h)) = sizes {
            println!("  frames are {w}×{h}");
        }
        if let Some(v) = frames.vocabulary() {
            println!(
                "  vocabulary: {} classes of dimension {} ({})",
                v.names.len(),
                v.dim,
                v.model
            );
        }
    }
    match first_error {
        Some(e) => anyhow::bail!("the log is damaged: {e}"),
        None => Ok(()),
    }
}
