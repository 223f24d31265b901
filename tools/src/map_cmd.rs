//! `latentam map`: a log in, a run folder out.

use std::path::PathBuf;

use anyhow::{bail, Result};
use latentam::runs::{Kept, RunFolder, Written, STATE_FILE};
use latentam::text::shown_path;
use latentam::Ending;

use crate::config_args::ConfigArgs;
use crate::input_args::InputArgs;
use crate::mapping::{map_log, summary, write_folder, RunOptions, RUN_FILES};

#[derive(clap::Args)]
pub struct Args {
    /// Input MCAP log (a file, or a rosbag2 folder of them).
    log: PathBuf,
    /// Run folder to write (created if missing). It is replaced whole, and
    /// only once something was mapped: a failed run leaves it as it was.
    /// One process at a time may write it.
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
    /// Write the run folder every N keyframes while mapping (0: only at
    /// the end), so a crash or a lost device loses at most N keyframes:
    /// `--resume` continues from the last save.
    #[arg(long, value_name = "N", default_value_t = 25)]
    autosave_every: u64,
    /// Keep mapping when an autosave fails (each failure is printed and
    /// listed in report.json); by default a failed autosave stops the run
    /// with exit status 1, since the folder would not be written at the
    /// end either.
    #[arg(long)]
    continue_after_failed_autosave: bool,
    #[command(flatten)]
    live: crate::live_args::LiveViewArgs,
}

/// Exit status of a run stopped by Ctrl-C after writing its folder.
pub const INTERRUPTED: u8 = 130;

/// Runs the command; `Ok(true)` when it was interrupted.
pub fn run(args: Args) -> Result<bool> {
    let config = args.config.load()?;
    let assembly = args.input.assembly()?;
    args.live.check()?;
    // What the command reads is never inside what it replaces.
    let mut inputs = vec![("the log", args.log.as_path())];
    inputs.extend(args.config.config.as_deref().map(|c| ("--config", c)));
    crate::own_inputs::refuse_inputs_inside(&args.out, &inputs)?;
    // Taken before anything is read: no other process writes the folder
    // while this run reads its state or replaces it.
    let folder = RunFolder::lock(&args.out)?;
    if args.resume && !folder.dir().join(STATE_FILE).exists() {
        bail!(
            "--resume: {} holds no saved map ({STATE_FILE} missing)",
            args.out.display()
        );
    }
    let mut run = map_log(
        &RunOptions {
            log: args.log.clone(),
            assembly,
            config,
            max_frames: args.frames,
            resume: args.resume.then(|| args.config.clone()),
            profile: !args.no_trace,
            autosave_every: args.autosave_every,
            continue_after_failed_autosave: args.continue_after_failed_autosave,
            live: Some(args.live.clone()).filter(|l| l.live.is_some()),
        },
        Some(&folder),
    )?;
    let report = match write_folder(&mut run, &folder) {
        Ok(Written::Saved(report)) => {
            print!("{}", summary(&report));
            println!("run folder {}:", shown_path(&args.out));
            for f in RUN_FILES {
                if args.out.join(f).exists() {
                    println!("  {}", shown_path(&args.out.join(f)));
                }
            }
            Ok(report)
        }
        Ok(Written::Kept(why)) => {
            eprintln!(
                "{}: not replaced: {why}; the folder keeps {}",
                args.out.display(),
                run.kept_description()
            );
            Err(why)
        }
        Err(e) => {
            // Why the run stopped, when it did, comes first.
            let why = match &run.ending {
                Ending::Failed(reason) => format!("{reason}; "),
                _ => String::new(),
            };
            return Err(e.context(format!(
                "{why}{} not replaced; it keeps {}",
                args.out.display(),
                run.kept_description()
            )));
        }
    };
    match (&run.ending, report) {
        (Ending::Failed(e), Ok(_)) => bail!(
            "{e} (what was mapped before is in {}; see report.json)",
            args.out.display()
        ),
        (Ending::Failed(e), Err(_)) => bail!("{e}"),
        (Ending::Interrupted, Err(_)) => {
            eprintln!("interrupted before a new frame was mapped");
            Ok(true)
        }
        // Resumed on a log whose frames were all mapped already.
        (_, Err(Kept::NothingNew)) => Ok(false),
        (_, Err(Kept::NothingMapped(why))) => bail!("no map was written: {why}"),
        (_, Err(Kept::Broken)) => bail!("no map was written: a keyframe failed part-way"),
        (Ending::Interrupted, Ok(report)) => {
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
