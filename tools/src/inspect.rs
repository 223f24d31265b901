//! `latentam inspect`: what a log holds and what the engine makes of it.

use latentam::text::{shown, shown_path};
use std::path::{Path, PathBuf};

use latentam::frames::{McapFrames, PoseSource};
use latentam::logs::{McapLog, Metadata};

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

/// Metadata values longer than this (rosbag2's `serialized_metadata`, a
/// whole YAML document) are summarised, not printed.
const SHORT: usize = 160;

/// A metadata value as printed: escaped, or summarised when long.
fn summarised(v: &str) -> String {
    if v.len() <= SHORT && !v.contains('\n') {
        shown(v)
    } else {
        format!(
            "({} bytes, {} lines; not shown)",
            v.len(),
            v.lines().count()
        )
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let log = McapLog::open(&args.log)?;
    let metadata = log.metadata()?;
    let channels = log.channels();
    let range = log.time_range();
    if !args.json {
        println!("{}:", shown_path(&args.log));
        for (file, why) in log.unindexed_files() {
            println!("  warning: {}: {}", shown_path(file), shown(why));
        }
        if let Some((a, b)) = range {
            println!("  {:.1} s of messages", (b.saturating_sub(a)) as f64 * 1e-9);
        }
        for c in &channels {
            let n = log
                .message_count(&c.topic)
                .map_or("?".into(), |n| n.to_string());
            println!(
                "  {:<32} {:>7} × {}",
                shown(&c.topic),
                n,
                shown(&c.schema_name)
            );
        }
        for (name, values) in &metadata {
            for (k, v) in values {
                println!("  metadata {}.{}: {}", shown(name), shown(k), summarised(v));
            }
        }
    }
    let config = args.input.assembly()?;
    let mut frames = McapFrames::from_log(log.clone(), config)?;
    if !args.json {
        for line in frames.topic_plan() {
            println!("  chosen by type: {}", shown(&line.to_string()));
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
        let doc = json_document(&args.log, &log, &metadata, &frames, sizes);
        println!("{}", serde_json::to_string_pretty(&doc)?);
    } else {
        print!("{}", shown(&frames.report().to_string()));
        if let Some((w, h)) = sizes {
            println!("  frames are {w}×{h}");
        }
        if let Some(v) = frames.vocabulary() {
            println!(
                "  vocabulary: {} classes of dimension {} ({})",
                v.names.len(),
                v.dim,
                shown(&v.model)
            );
        }
    }
    match first_error {
        Some(e) => anyhow::bail!("the log is damaged: {e}"),
        None => Ok(()),
    }
}

/// What `inspect --json` prints: topics, metadata, the streams chosen,
/// the frame size and the ingest report.
fn json_document(
    path: &Path,
    log: &McapLog,
    metadata: &[(String, Metadata)],
    frames: &McapFrames,
    sizes: Option<(u32, u32)>,
) -> serde_json::Value {
    let channels = log.channels();
    let range = log.time_range();
    let topics: Vec<_> = channels
        .iter()
        .map(|c| {
            serde_json::json!({
                "topic": c.topic,
                "type": c.schema_name,
                "count": log.message_count(&c.topic),
            })
        })
        .collect();
    let meta: serde_json::Map<String, serde_json::Value> = metadata
        .iter()
        .flat_map(|(name, values)| {
            values
                .iter()
                .map(move |(k, v)| (format!("{name}.{k}"), summarised(v).into()))
        })
        .collect();
    let t = frames.topics();
    let pose = match &t.pose {
        PoseSource::Topic(p) => p.clone(),
        PoseSource::Tf { world_frame, .. } if world_frame.is_empty() => {
            "/tf (from the root of the tree)".into()
        }
        PoseSource::Tf { world_frame, .. } => format!("/tf (from {world_frame})"),
    };
    serde_json::json!({
        "log": path.display().to_string(),
        "files_without_summary": log.unindexed_files().len(),
        "duration_s": range.map(|(a, b)| b.saturating_sub(a) as f64 * 1e-9),
        "topics": topics,
        "metadata": meta,
        "streams": {
            "color": t.color,
            "depth": t.depth,
            "camera_info": t.camera_info,
            "pose": pose,
            "embeddings": t.embeddings,
            "semantic": t.semantic,
            "vocabulary": t.vocabulary,
        },
        "chosen_by_type": frames.topic_plan(),
        "frame_size": sizes.map(|(w, h)| [w, h]),
        "ingest": frames.report(),
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn long_metadata_is_summarised() {
        assert_eq!(super::summarised("jazzy"), "jazzy");
        let yaml = "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n";
        assert_eq!(
            super::summarised(yaml),
            format!("({} bytes, 3 lines; not shown)", yaml.len())
        );
        assert!(super::summarised(&"x".repeat(500)).starts_with("(500 bytes"));
    }
}
