//! Mapping a log, and the run folder it leaves: the loop shared by
//! `latentam map`, `profile` and `demo`.
//!
//! The run folder is replaced whole (see [`RunFolder`]): every autosave and
//! the final write put a complete, consistent version in place, or leave
//! the previous one. A run that stops early (Ctrl-C, a frame limit, an
//! unreadable frame, a frame refused for its content) still writes what
//! was mapped, with the failure in `report.json`; a failure in the middle
//! of a keyframe, or a run that mapped nothing, leaves the folder as it
//! was.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context as _, Result};
use latentam::gpu::{Context, ContextOptions, KernelStats};
use latentam::io::{write_tum, AssemblyConfig, CameraPose, IngestReport, McapFrames, McapLog};
use latentam::map::{write_ply, write_ply_without_latents};
use latentam::mapper::budget::MemorySplit;
use latentam::mapper::{
    Integrated, KeyframeGpuCalls, KeyframeReport, KeyframeTimings, Mapper, MapperConfig,
};
use latentam::mapper::{RunFolder, DECODER_FILE, STATE_FILE};
use serde::Serialize;

use crate::interrupt;
use latentam_cli::progress::StatusLine;

/// What to map.
pub struct RunOptions {
    /// The input log.
    pub log: PathBuf,
    /// How its messages become frames.
    pub assembly: AssemblyConfig,
    /// The effective configuration (ignored when resuming: the saved
    /// state's shape-defining settings win, see `OnlineMapper::load`).
    pub config: MapperConfig,
    /// Stop after this many frames of the log.
    pub max_frames: Option<usize>,
    /// Continue the state saved in the run folder, with these settings
    /// applied over its own.
    pub resume: Option<crate::config_cmd::ConfigArgs>,
    /// Time every kernel (for `trace.json` and the profile table).
    pub profile: bool,
    /// Write the run folder every this many keyframes while mapping (0:
    /// only at the end).
    pub autosave_every: u64,
}

/// How a run ended.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Ending {
    /// The log ended.
    Complete,
    /// `--frames` was reached.
    FrameLimit,
    /// Ctrl-C / SIGTERM.
    Interrupted,
    /// The run was still going when this folder was written (an
    /// autosave); a later write replaces it.
    Running,
    /// An error stopped it; what was mapped before is kept.
    Failed(String),
}

/// A finished (or stopped) run.
pub struct Run {
    pub ctx: Context,
    pub mapper: Mapper,
    pub log: PathBuf,
    /// Frames offered to the mapper in this run.
    pub frames: u64,
    /// Frames skipped because the resumed state had mapped them.
    pub skipped: u64,
    pub keyframes: Vec<KeyframeReport>,
    pub wall_s: f64,
    pub ending: Ending,
    pub ingest: IngestReport,
    /// Keyframe count at the last successful autosave.
    pub autosaved_at: Option<u64>,
    /// Autosaves that failed (mapping went on).
    pub autosave_failures: Vec<String>,
    /// Frames that reached the mapper and were not keyframes.
    pub not_keyframes: u64,
}

/// What [`Run::write_folder`] did.
pub enum Written {
    /// The folder now holds this run, described by the report.
    Saved(Box<RunReport>),
    /// The folder was left as it was, for this reason.
    Kept(Kept),
}

/// Why [`Run::write_folder`] left the folder as it was.
#[derive(Debug)]
pub enum Kept {
    /// A resumed run whose log frames were all mapped already: the folder
    /// holds this map.
    NothingNew,
    /// No keyframe, or no Gaussian, came of the log (the reasons, counted).
    NothingMapped(String),
    /// A keyframe failed part-way: the map is neither before nor after it.
    Broken,
}

impl std::fmt::Display for Kept {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Kept::NothingNew => write!(
                f,
                "no new frame was mapped; the folder keeps the map it holds"
            ),
            Kept::NothingMapped(why) => write!(f, "nothing was mapped ({why})"),
            Kept::Broken => write!(f, "a keyframe failed part-way, so the map cannot be saved"),
        }
    }
}

/// Status line of a running map.
struct MapProgress {
    start: Instant,
    line: StatusLine,
    total: Option<usize>,
}

impl MapProgress {
    fn new(total: Option<usize>) -> Self {
        MapProgress {
            start: Instant::now(),
            line: StatusLine::default(),
            total,
        }
    }

    fn update(&mut self, frames: u64, mapper: &Mapper, last_report: Option<&KeyframeReport>) {
        if !self.line.due() {
            return;
        }
        let elapsed = self.start.elapsed().as_secs_f64().max(1e-9);
        let stats = mapper.stats();
        let of = self.total.map_or(String::new(), |t| format!("/{t}"));
        // A bar and the time left, when the number of frames is known.
        let bar = match self.total {
            Some(t) if t > 0 => {
                let done = (frames as f64 / t as f64).min(1.0);
                let filled = (done * 20.0).round() as usize;
                let left = elapsed * (1.0 - done) / done.max(1e-9);
                format!(
                    "[{}{}] {:>3.0}% {} left · ",
                    "#".repeat(filled),
                    "-".repeat(20 - filled),
                    done * 100.0,
                    duration(left)
                )
            }
            _ => String::new(),
        };
        let (gaussians, resident, gpu) = match last_report {
            Some(k) => (k.gaussians, k.resident, k.gpu_bytes),
            None => (stats.gaussians, stats.resident, stats.gpu_bytes),
        };
        let line = format!(
            "mapping: {bar}frame {frames}{of} · {} keyframes ({:.2}/s) · Gaussians {resident} on \
             GPU, {gaussians} in map · GPU {:.1} MB",
            stats.keyframes,
            stats.keyframes as f64 / elapsed,
            gpu as f64 / 1e6,
        );
        self.line.show(&line);
    }

    fn finish(&self) {
        self.line.finish();
    }
}

/// `1h02m`, `3m05s`, `42s`.
fn duration(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    match s {
        0..=59 => format!("{s}s"),
        60..=3599 => format!("{}m{:02}s", s / 60, s % 60),
        _ => format!("{}h{:02}m", s / 3600, s % 3600 / 60),
    }
}

/// Maps `opts.log`, writing the run folder `folder` at every autosave
/// (when given); errors only when nothing could start (no device, an
/// unreadable log or state). Failures part-way end the run with
/// [`Ending::Failed`]. The final write is the caller's
/// ([`Run::write_folder`]).
pub fn map_log(opts: &RunOptions, folder: Option<&RunFolder>) -> Result<Run> {
    let ctx = Context::new(ContextOptions {
        profiling: opts.profile,
        ..ContextOptions::default()
    })?;
    latentam::mapper::warm_up(&ctx)?;
    let mapper = match (folder, &opts.resume) {
        (Some(folder), Some(settings)) => {
            let settings = |saved: &MapperConfig| {
                settings
                    .load_over(saved.clone())
                    .map_err(|e| latentam::Error::InvalidArgument(format!("{e:#}")))
            };
            Mapper::load_with(&ctx, folder.dir(), &settings)
                .with_context(|| format!("loading the saved state in {}", folder.dir().display()))?
        }
        _ => Mapper::with_context(&ctx, opts.config.clone())?,
    };
    // Profile the mapping, not the warm-up or the load.
    ctx.profiler_reset();
    let log =
        McapLog::open(&opts.log).with_context(|| format!("opening {}", opts.log.display()))?;
    let mut frames = McapFrames::from_log(log.clone(), opts.assembly.clone())
        .with_context(|| format!("opening {}", opts.log.display()))?;
    // Colour images bound the frames; the summary says how many there are.
    let in_log = log
        .message_count(&frames.topics().color)
        .map(|n| n as usize);
    for line in frames.topic_plan() {
        eprintln!("input: {line}");
    }
    // Resume after the last frame the saved state integrated, by stamp; a
    // state from before stamps were saved resumes by count.
    let skip_by_count = match mapper.stats().last_frame_stamp_ns {
        Some(_) => 0,
        None => mapper.stats().frames,
    };
    let limit = opts.max_frames.unwrap_or(usize::MAX);
    let total = match (in_log, opts.max_frames) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    };
    let mut progress = MapProgress::new(total);
    let mut run = Run {
        ctx,
        mapper,
        log: opts.log.clone(),
        frames: 0,
        skipped: 0,
        keyframes: Vec::new(),
        wall_s: 0.0,
        ending: Ending::Running,
        ingest: IngestReport::default(),
        autosaved_at: None,
        autosave_failures: Vec::new(),
        not_keyframes: 0,
    };
    let start = Instant::now();
    interrupt::install();
    run.mapper.set_hurry_flag(interrupt::flag());
    let ending = loop {
        if interrupt::requested() {
            break Ending::Interrupted;
        }
        if (run.skipped + run.frames) as usize >= limit {
            break Ending::FrameLimit;
        }
        let Some(frame) = frames.next() else {
            break Ending::Complete;
        };
        let frame = match frame {
            Ok(f) => f,
            Err(e) => break Ending::Failed(format!("reading {}: {e}", opts.log.display())),
        };
        if run.mapper.already_mapped(&frame) || run.skipped < skip_by_count {
            run.skipped += 1;
            frames.recycle(frame);
            continue;
        }
        match run.mapper.integrate(&frame) {
            Ok(Integrated::Keyframe(k)) => {
                run.frames += 1;
                run.keyframes.push(*k);
                let n = run.mapper.stats().keyframes;
                if let Some(folder) = folder.filter(|_| opts.autosave_every > 0) {
                    if n % opts.autosave_every == 0 {
                        run.wall_s = start.elapsed().as_secs_f64();
                        run.ingest = frames.report().clone();
                        match run.write_folder(folder) {
                            Ok(Written::Saved(_)) => run.autosaved_at = Some(n),
                            Ok(Written::Kept(_)) => {}
                            Err(e) => {
                                let e = describe(&e);
                                eprintln!("warning: autosave at keyframe {n} failed: {e}");
                                run.autosave_failures.push(format!("keyframe {n}: {e}"));
                            }
                        }
                    }
                }
            }
            Ok(Integrated::Skipped) => {
                run.frames += 1;
                run.not_keyframes += 1;
            }
            Err(e) => {
                break Ending::Failed(format!("mapping frame at {} ns: {e}", frame.stamp_ns));
            }
        }
        frames.recycle(frame);
        progress.update(run.skipped + run.frames, &run.mapper, run.keyframes.last());
    };
    progress.finish();
    run.ending = ending;
    run.wall_s = start.elapsed().as_secs_f64();
    run.ingest = frames.report().clone();
    Ok(run)
}

/// `report.json`.
#[derive(Serialize)]
pub struct RunReport {
    /// Shared by every file of this version of the run folder.
    pub run_id: String,
    pub log: String,
    pub device: String,
    pub ending: Ending,
    pub frames: u64,
    pub frames_skipped_as_already_mapped: u64,
    pub keyframes: u64,
    pub wall_s: f64,
    /// Frames per second of wall time, end to end (reading, decoding,
    /// mapping; embeddings come precomputed in the log).
    pub fps: f64,
    pub keyframes_per_s: f64,
    pub gaussians: usize,
    pub resident: usize,
    pub gpu_budget: u64,
    pub window_capacity: u64,
    pub peak_gpu_bytes: u64,
    /// Peak GPU bytes by part (images, latent head, window, staging).
    pub peak_gpu_split: MemorySplit,
    pub peak_cpu_bytes: u64,
    pub evicted: u64,
    pub fetched: u64,
    pub ms_per_keyframe: KeyframeTimings,
    /// What each keyframe asked of the GPU: host waits (each a CPU–GPU
    /// round trip; in all and in Stage I + II), submissions, dispatches.
    pub host_waits_per_keyframe: HostWaits,
    pub paging_hidden_share: Option<f64>,
    pub dedicated_transfer_queue: bool,
    pub embedding_model: Option<String>,
    /// Keyframe count of the last autosave, and autosaves that failed.
    pub autosaved_at: Option<u64>,
    pub autosave_failures: Vec<String>,
    pub ingest: IngestReport,
    /// Per kernel, when profiled.
    pub kernels: BTreeMap<&'static str, KernelStats>,
    pub keyframe_reports: Vec<KeyframeReport>,
}

/// Host waits per keyframe (mean and most), in all and in Stage I and
/// Stage II together, with the mean submissions and dispatches.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct HostWaits {
    pub mean: f64,
    pub max: u64,
    pub stage_one_and_two_mean: f64,
    pub stage_one_and_two_max: u64,
    pub submissions_mean: f64,
    pub dispatches_mean: f64,
}

impl HostWaits {
    /// Over the keyframes' [`KeyframeReport::gpu_calls`].
    pub fn of(keyframes: &[KeyframeGpuCalls]) -> Self {
        let n = keyframes.len().max(1) as f64;
        let mean = |f: &dyn Fn(&KeyframeGpuCalls) -> u64| {
            keyframes.iter().map(|k| f(k) as f64).sum::<f64>() / n
        };
        let max = |f: &dyn Fn(&KeyframeGpuCalls) -> u64| keyframes.iter().map(f).max().unwrap_or(0);
        let all = |k: &KeyframeGpuCalls| k.total().host_waits;
        let training = |k: &KeyframeGpuCalls| k.training().host_waits;
        HostWaits {
            mean: mean(&all),
            max: max(&all),
            stage_one_and_two_mean: mean(&training),
            stage_one_and_two_max: max(&training),
            submissions_mean: mean(&|k| k.total().submissions),
            dispatches_mean: mean(&|k| k.total().dispatches),
        }
    }

    /// One line for a summary.
    pub fn summary(&self) -> String {
        format!(
            "host waits on the GPU per keyframe: {:.1} on average, {} at most ({:.1} and {} in \
             Stage I + II); {:.1} submissions and {:.0} dispatches on average",
            self.mean,
            self.max,
            self.stage_one_and_two_mean,
            self.stage_one_and_two_max,
            self.submissions_mean,
            self.dispatches_mean
        )
    }
}

/// Per-keyframe means of timings summed over `n` keyframes.
pub fn mean_timings(t: &KeyframeTimings, n: u64) -> KeyframeTimings {
    let n = n.max(1) as f64;
    let s = |x: f64| x / n;
    KeyframeTimings {
        kmeans_ms: s(t.kmeans_ms),
        insertion_ms: s(t.insertion_ms),
        stage_one_ms: s(t.stage_one_ms),
        stage_two_ms: s(t.stage_two_ms),
        stage_two_gpu_ms: t.stage_two_gpu_ms.map(s),
        paging_cpu_ms: s(t.paging_cpu_ms),
        paging_gpu_ms: t.paging_gpu_ms.map(s),
        paging_hidden_ms: t.paging_hidden_ms.map(s),
        prune_ms: s(t.prune_ms),
        total_ms: s(t.total_ms),
    }
}

impl Run {
    /// The report of this run, with the profiler's per-kernel statistics.
    fn report_with(&self, run_id: &str, kernels: BTreeMap<&'static str, KernelStats>) -> RunReport {
        let stats = self.mapper.stats();
        let t = &stats.timings;
        RunReport {
            run_id: run_id.to_string(),
            log: self.log.display().to_string(),
            device: self.ctx.info().name.clone(),
            ending: self.ending.clone(),
            frames: self.frames,
            frames_skipped_as_already_mapped: self.skipped,
            keyframes: stats.keyframes,
            wall_s: self.wall_s,
            fps: self.frames as f64 / self.wall_s.max(1e-9),
            keyframes_per_s: self.keyframes.len() as f64 / self.wall_s.max(1e-9),
            gaussians: stats.gaussians,
            resident: stats.resident,
            gpu_budget: stats.window.map_or(0, |w| w.budget),
            window_capacity: stats.window.map_or(0, |w| w.capacity),
            peak_gpu_bytes: stats.gpu_peak_bytes,
            peak_gpu_split: stats.gpu_peak_split,
            peak_cpu_bytes: stats.cpu_peak_bytes,
            evicted: stats.evicted,
            fetched: stats.fetched,
            ms_per_keyframe: mean_timings(t, stats.keyframes),
            host_waits_per_keyframe: HostWaits::of(
                &self
                    .keyframes
                    .iter()
                    .map(|k| k.gpu_calls)
                    .collect::<Vec<_>>(),
            ),
            paging_hidden_share: match (t.paging_gpu_ms, t.paging_hidden_ms) {
                (Some(g), Some(h)) if g > 0.0 => Some(h / g),
                _ => None,
            },
            dedicated_transfer_queue: self.ctx.info().dedicated_transfer_queue,
            embedding_model: self.mapper.embedding_model().map(str::to_string),
            ingest: self.ingest.clone(),
            autosaved_at: self.autosaved_at,
            autosave_failures: self.autosave_failures.clone(),
            kernels,
            keyframe_reports: self.keyframes.clone(),
        }
    }

    /// The keyframe trajectory, every keyframe of the map (resumed runs
    /// included), camera-to-world.
    pub fn trajectory(&self) -> Vec<(u64, CameraPose)> {
        self.mapper
            .trajectory()
            .iter()
            .map(|&(stamp, pose)| (stamp.max(0) as u64, pose))
            .collect()
    }

    /// Why the run folder must not be replaced by this run, if so.
    pub fn not_to_save(&self) -> Option<Kept> {
        let stats = self.mapper.stats();
        if self.mapper.is_broken() {
            Some(Kept::Broken)
        } else if self.frames == 0 && self.skipped > 0 && stats.gaussians > 0 {
            Some(Kept::NothingNew)
        } else if stats.keyframes == 0 || stats.gaussians == 0 {
            Some(Kept::NothingMapped(self.why_nothing()))
        } else {
            None
        }
    }

    /// What the folder holds when this run did not replace it.
    pub fn kept_description(&self) -> String {
        match self.autosaved_at {
            Some(k) => format!("its autosave at keyframe {k}"),
            None => "the run it held before, if any".into(),
        }
    }

    /// Why no keyframe (or no Gaussian) came of the log, with counts.
    pub fn why_nothing(&self) -> String {
        let mut parts = Vec::new();
        let stats = self.mapper.stats();
        if stats.keyframes > 0 {
            parts.push(format!(
                "{} keyframes seeded no Gaussian: their depth gave no point within range",
                stats.keyframes
            ));
        }
        parts.push(format!(
            "{} frames assembled from {} messages",
            self.ingest.frames, self.ingest.messages
        ));
        if self.not_keyframes > 0 {
            parts.push(format!("{} frames were not keyframes", self.not_keyframes));
        }
        for (reason, c) in &self.ingest.skipped {
            parts.push(format!("{} × {reason} (first: {})", c.count, c.first));
        }
        if let Ending::Failed(e) = &self.ending {
            parts.push(format!("stopped by: {e}"));
        }
        parts.join("; ")
    }

    /// Replaces the run folder with this run: the resumable state,
    /// `decoder.safetensors` (when the map has embeddings), `map.ply`,
    /// `config.toml`, `trajectory.txt`, `trace.json` (when profiled) and
    /// `report.json`, all with one run id. Either every file is written
    /// and the folder swapped in whole, or it is left as it was: kept for
    /// [`Run::not_to_save`]'s reasons, an error for a file that could not
    /// be written.
    pub fn write_folder(&mut self, folder: &RunFolder) -> Result<Written> {
        if let Some(why) = self.not_to_save() {
            return Ok(Written::Kept(why));
        }
        let staging = folder.stage()?;
        let dir = staging.path().to_path_buf();
        self.mapper
            .save_into(&staging)
            .context("saving the map (the folder keeps its last save)")?;
        let config = format!(
            "# The effective configuration of this run (`latentam map --config` reads it back;\n\
             # `latentam config --print-defaults` documents every key).\n{}",
            self.mapper.config().to_toml()
        );
        write_text(&dir.join("config.toml"), &config)?;
        let gaussians: Vec<_> = self.mapper.global().iter().map(|(_, g)| *g).collect();
        // A map without embeddings has no meaningful queries to write.
        if self.mapper.head().is_some() {
            write_ply(&dir.join("map.ply"), &gaussians, &[])?;
        } else {
            write_ply_without_latents(&dir.join("map.ply"), &gaussians, &[])?;
        }
        drop(gaussians);
        write_tum(&dir.join("trajectory.txt"), &self.trajectory())?;
        let profile = self.ctx.profiler_snapshot();
        if !profile.samples().is_empty() {
            profile.write_chrome_trace(&dir.join("trace.json"))?;
        }
        let report = self.report_with(staging.run_id(), profile.stats());
        write_text(
            &dir.join("report.json"),
            &serde_json::to_string_pretty(&report)?,
        )?;
        write_text(
            &dir.join("report.html"),
            &crate::report_html::report_html(&report)?,
        )?;
        staging
            .commit()
            .with_context(|| format!("replacing {}", folder.dir().display()))?;
        Ok(Written::Saved(Box::new(report)))
    }
}

/// Writes `text` to `path` whole or not at all.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    Ok(latentam::files::write_bytes_atomically(
        path,
        text.as_bytes(),
    )?)
}

/// An error and its causes in one line, without repeating a cause that
/// an outer message already quotes.
pub fn describe(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let c = cause.to_string();
        if !out.contains(&c) {
            if !out.is_empty() {
                out.push_str(": ");
            }
            out.push_str(&c);
        }
    }
    out
}

/// The files of a run folder, for the summary.
pub const RUN_FILES: &[&str] = &[
    "map.ply",
    DECODER_FILE,
    "config.toml",
    "report.json",
    "report.html",
    "trace.json",
    "trajectory.txt",
    STATE_FILE,
];

/// A human summary of a run.
pub fn summary(r: &RunReport) -> String {
    let m = &r.ms_per_keyframe;
    let mut s = format!(
        "{} frames, {} keyframes in {:.1} s ({:.2} frames/s, {:.3} keyframes/s) on {}\n",
        r.frames, r.keyframes, r.wall_s, r.fps, r.keyframes_per_s, r.device
    );
    s += &format!(
        "Gaussians: {} in the map, {} on the GPU (window of {}); evicted {}, fetched {}\n",
        r.gaussians, r.resident, r.window_capacity, r.evicted, r.fetched
    );
    s += &format!(
        "memory: peak GPU {:.1} MB of a {:.1} MB budget, peak CPU {:.1} MB\n",
        r.peak_gpu_bytes as f64 / 1e6,
        r.gpu_budget as f64 / 1e6,
        r.peak_cpu_bytes as f64 / 1e6
    );
    s += &format!(
        "per keyframe: {:.0} ms (k-means {:.0}, insertion {:.0}, Stage I {:.0}, Stage II + paging \
         {:.0}, pruning {:.0})\n",
        m.total_ms, m.kmeans_ms, m.insertion_ms, m.stage_one_ms, m.stage_two_ms, m.prune_ms
    );
    s += &r.host_waits_per_keyframe.summary();
    s.push('\n');
    let skipped = r.ingest.total_skipped();
    if skipped > 0 {
        s += &format!("input: {skipped} messages or frames skipped (see report.json `ingest`)\n");
    }
    s
}
