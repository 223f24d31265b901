//! `latentam inspect`: what a log holds and what the engine makes of it.

use std::path::PathBuf;

use latentam::io::{McapFrames, McapLog};

#[derive(clap::Args)]
pub struct Args {
    /// An MCAP file or a rosbag2 directory of split files.
    log: PathBuf,
    #[command(flatten)]
    input: crate::input_args::InputArgs,
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
    let config = args.input.assembly()?;
    let mut frames = McapFrames::from_log(log, config)?;
    if !args.json {
        for line in frames.topic_plan() {
            println!("  chosen by type: {line}");
        }
    }
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
