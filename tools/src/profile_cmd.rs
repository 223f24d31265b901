//! `latentam profile`: maps a log with every kernel timed and prints the
//! per-kernel table; writes the Chrome/Perfetto trace.

use std::path::PathBuf;

use anyhow::{bail, Result};

use crate::config_args::ConfigArgs;
use crate::input_args::InputArgs;
use crate::mapping::{map_log, RunOptions};
use latentam::Ending;

#[derive(clap::Args)]
pub struct Args {
    /// Input MCAP log.
    log: PathBuf,
    /// Map at most this many frames.
    #[arg(long, value_name = "N")]
    frames: Option<usize>,
    #[command(flatten)]
    config: ConfigArgs,
    #[command(flatten)]
    input: InputArgs,
    /// Where to write the trace (open it in https://ui.perfetto.dev or
    /// chrome://tracing).
    #[arg(long, default_value = "trace.json")]
    trace: PathBuf,
}

pub fn run(args: Args) -> Result<()> {
    let run = map_log(
        &RunOptions {
            log: args.log.clone(),
            assembly: args.input.assembly()?,
            config: args.config.load()?,
            max_frames: args.frames,
            resume: None,
            profile: true,
            autosave_every: 0,
            continue_after_failed_autosave: false,
            live: None,
        },
        None,
    )?;
    if let Ending::Failed(e) = &run.ending {
        bail!("{e}");
    }
    let profile = run.context().profiler_snapshot();
    if profile.stats().is_empty() {
        bail!(
            "no kernel was timed: {} has no timestamp support on its compute queue",
            run.context().info().name
        );
    }
    let wall_ms = run.wall_s * 1e3;
    let frames = run.frames.max(1) as f64;
    println!(
        "{} frames, {} keyframes in {:.1} s on {}: {:.1} ms per frame; kernels busy {:.1} ms \
         per frame ({:.0} % of the wall time)",
        run.frames,
        run.keyframes.len(),
        run.wall_s,
        run.context().info().name,
        wall_ms / frames,
        profile.total_ms() / frames,
        100.0 * profile.total_ms() / wall_ms.max(1e-9)
    );
    println!("share = kernel time / wall time of the frames mapped");
    print!("{}", profile.table_with_share_of(wall_ms));
    profile.write_chrome_trace(&args.trace)?;
    if profile.dropped() > 0 {
        println!(
            "trace: {} (the first {} commands; {} more were timed for the table)",
            args.trace.display(),
            profile.samples().len(),
            profile.dropped()
        );
    } else {
        println!("trace: {}", args.trace.display());
    }
    Ok(())
}
