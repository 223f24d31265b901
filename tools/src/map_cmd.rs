//! `latentam map`: a log in, a run folder out.

use std::path::PathBuf;

use anyhow::{bail, Result};

use crate::config_cmd::ConfigArgs;
use crate::input_args::InputArgs;
use crate::mapping::{map_log, summary, Ending, RunOptions, RUN_FILES};

#[derive(clap::Args)]
pub struct Args {
    /// Input MCAP log (a file, or a rosbag2 folder of them).
    log: PathBuf,
    /// Run folder to write (created if missing; its files are replaced).
    #[arg(short, long)]
    out: PathBuf,
    #[command(flatten)]
    config: ConfigArgs,
    #[command(flatten)]
    input: InputArgs,
    /// Map at most this many frames of the log.
    #[arg(long, value_name = "N")]
    frames: Option<usize>,
    /// Continue the map saved in --out: its frames are skipped in the log
    /// and mapping goes on from there (--config/--set change only run-time
    /// settings then).
    #[arg(long)]
    resume: bool,
    /// Do not time kernels: no trace.json and no per-kernel table in
    /// report.json, for a little less overhead.
    #[arg(long)]
    no_trace: bool,
    /// Save the resumable state every N keyframes while mapping (0: only
    /// at the end), so a crash or a lost device loses at most N
    /// keyframes: `--resume` continues from the last save.
    #[arg(long, value_name = "N", default_value_t = 25)]
    autosave_every: u64,
}

/// Exit status of a run stopped by Ctrl-C after writing its folder.
pub const INTERRUPTED: u8 = 130;

/// Runs the command; `Ok(true)` when it was interrupted.
pub fn run(args: Args) -> Result<bool> {
    let config = args.config.load()?;
    if args.resume && !args.out.join(latentam::mapper::STATE_FILE).exists() {
        bail!(
            "--resume: {} holds no saved map ({} missing)",
            args.out.display(),
            latentam::mapper::STATE_FILE
        );
    }
    let mut run = map_log(&RunOptions {
        log: args.log.clone(),
        assembly: args.input.assembly()?,
        config,
        max_frames: args.frames,
        resume: args.resume.then(|| args.out.clone()),
        profile: !args.no_trace,
        autosave: (args.autosave_every > 0).then(|| (args.out.clone(), args.autosave_every)),
    })?;
    let report = run.write_folder(&args.out)?;
    print!("{}", summary(&report));
    for p in &report.problems {
        eprintln!("error: {p}");
    }
    println!("run folder {}:", args.out.display());
    for f in RUN_FILES {
        if args.out.join(f).exists() {
            println!("  {}", args.out.join(f).display());
        }
    }
    match run.ending {
        Ending::Failed(e) => bail!(
            "{e} (what was mapped before is in {}; see report.json)",
            args.out.display()
        ),
        _ if !report.problems.is_empty() => bail!(
            "the run folder {} is incomplete (see above and report.json)",
            args.out.display()
        ),
        Ending::Interrupted => {
            eprintln!(
                "interrupted: the run folder holds the {} frames mapped; `latentam map {} --out {} \
                 --resume` continues",
                report.frames,
                args.log.display(),
                args.out.display()
            );
            Ok(true)
        }
        _ => Ok(false),
    }
}
