//! Mapping a log, and the run folder it leaves: the loop shared by
//! `latentam map`, `profile` and `demo`.
//!
//! A run that stops early (Ctrl-C, a frame limit, an unreadable frame or a
//! mapping error part-way) still writes a complete, valid run folder of
//! what was mapped; the failure is recorded in `report.json` and returned
//! afterwards.

use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context as _, Result};
use latentam::gpu::{Context, ContextOptions, KernelStats};
use latentam::io::{
    write_ply, write_tum, AssemblyConfig, CameraPose, IngestReport, McapFrames, McapLog,
};
use latentam::mapper::budget::MemorySplit;
use latentam::mapper::{Integrated, KeyframeReport, KeyframeTimings, Mapper, MapperConfig};
use latentam::mapper::{DECODER_FILE, STATE_FILE};
use serde::Serialize;

use crate::interrupt;

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
    /// Continue the state saved in this run folder.
    pub resume: Option<PathBuf>,
    /// Time every kernel (for `trace.json` and the profile table).
    pub profile: bool,
    /// Save the resumable state into this folder every this many
    /// keyframes.
    pub autosave: Option<(PathBuf, u64)>,
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
}

/// Status line of a running map: a line redrawn in place on a terminal,
/// a plain line every ten seconds otherwise.
struct MapProgress {
    start: Instant,
    last: Option<Instant>,
    terminal: bool,
    total: Option<usize>,
}

impl MapProgress {
    fn new(total: Option<usize>) -> Self {
        MapProgress {
            start: Instant::now(),
            last: None,
            terminal: std::io::stderr().is_terminal(),
            total,
        }
    }

    fn update(&mut self, frames: u64, mapper: &Mapper, last_report: Option<&KeyframeReport>) {
        let every = if self.terminal { 0.1 } else { 10.0 };
        if self.last.is_some_and(|t| t.elapsed().as_secs_f64() < every) {
            return;
        }
        self.last = Some(Instant::now());
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
        if self.terminal {
            eprint!("\r{line}\x1b[K");
        } else {
            eprintln!("{line}");
        }
    }

    fn finish(&self) {
        if self.terminal && self.last.is_some() {
            eprintln!();
        }
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

/// Maps `opts.log`; errors only when nothing could start (no device, an
/// unreadable log or state). Failures part-way end the run with
/// [`Ending::Failed`].
pub fn map_log(opts: &RunOptions) -> Result<Run> {
    let ctx = Context::new(ContextOptions {
        profiling: opts.profile,
        ..ContextOptions::default()
    })?;
    latentam::mapper::warm_up(&ctx)?;
    let mut mapper = match &opts.resume {
        Some(dir) => Mapper::load(&ctx, dir)
            .with_context(|| format!("loading the saved state in {}", dir.display()))?,
        None => Mapper::with_context(&ctx, opts.config.clone())?,
    };
    // Profile the mapping, not the warm-up or the load.
    ctx.profiler_reset();
    let log =
        McapLog::open(&opts.log).with_context(|| format!("opening {}", opts.log.display()))?;
    // Colour images bound the frames; the summary says how many there are.
    let in_log = log
        .message_count(&opts.assembly.topics.color)
        .map(|n| n as usize);
    let mut frames = McapFrames::from_log(log, opts.assembly.clone())
        .with_context(|| format!("opening {}", opts.log.display()))?;
    let skip = mapper.stats().frames;
    let limit = opts.max_frames.unwrap_or(usize::MAX);
    let total = match (in_log, opts.max_frames) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    };
    let mut progress = MapProgress::new(total);
    let mut keyframes = Vec::new();
    let (mut offered, mut skipped) = (0u64, 0u64);
    let mut ending = Ending::Complete;
    let (mut autosaved_at, mut autosave_failures) = (None, Vec::new());
    let start = Instant::now();
    interrupt::install();
    loop {
        if interrupt::requested() {
            ending = Ending::Interrupted;
            break;
        }
        if (skipped + offered) as usize >= limit {
            ending = Ending::FrameLimit;
            break;
        }
        let Some(frame) = frames.next() else {
            break;
        };
        let frame = match frame {
            Ok(f) => f,
            Err(e) => {
                ending = Ending::Failed(format!("reading {}: {e}", opts.log.display()));
                break;
            }
        };
        if skipped < skip {
            skipped += 1;
            frames.recycle(frame);
            continue;
        }
        offered += 1;
        match mapper.integrate(&frame) {
            Ok(Integrated::Keyframe(k)) => {
                keyframes.push(*k);
                if let Some((dir, every)) = &opts.autosave {
                    let n = mapper.stats().keyframes;
                    if *every > 0 && n % every == 0 {
                        match mapper.save(dir) {
                            Ok(_) => autosaved_at = Some(n),
                            Err(e) => {
                                eprintln!("warning: autosave at keyframe {n} failed: {e}");
                                autosave_failures.push(format!("keyframe {n}: {e}"));
                            }
                        }
                    }
                }
            }
            Ok(Integrated::Skipped) => {}
            Err(e) => {
                ending = Ending::Failed(format!("mapping frame at {} ns: {e}", frame.stamp_ns));
                break;
            }
        }
        frames.recycle(frame);
        progress.update(skipped + offered, &mapper, keyframes.last());
    }
    progress.finish();
    Ok(Run {
        ctx,
        mapper,
        log: opts.log.clone(),
        frames: offered,
        skipped,
        keyframes,
        wall_s: start.elapsed().as_secs_f64(),
        ending,
        ingest: frames.report().clone(),
        autosaved_at,
        autosave_failures,
    })
}

/// `report.json`.
#[derive(Serialize)]
pub struct RunReport {
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
    pub paging_hidden_share: Option<f64>,
    pub dedicated_transfer_queue: bool,
    pub embedding_model: Option<String>,
    /// Keyframe count of the last autosave, and autosaves that failed.
    pub autosaved_at: Option<u64>,
    pub autosave_failures: Vec<String>,
    /// Outputs that could not be written (see `latentam map`).
    pub problems: Vec<String>,
    pub ingest: IngestReport,
    /// Per kernel, when profiled.
    pub kernels: BTreeMap<&'static str, KernelStats>,
    pub keyframe_reports: Vec<KeyframeReport>,
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
    fn report_with(&self, kernels: BTreeMap<&'static str, KernelStats>) -> RunReport {
        let stats = self.mapper.stats();
        let t = &stats.timings;
        RunReport {
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
            paging_hidden_share: match (t.paging_gpu_ms, t.paging_hidden_ms) {
                (Some(g), Some(h)) if g > 0.0 => Some(h / g),
                _ => None,
            },
            dedicated_transfer_queue: self.ctx.info().dedicated_transfer_queue,
            embedding_model: self
                .mapper
                .online_ref()
                .embedding_model()
                .map(str::to_string),
            ingest: self.ingest.clone(),
            autosaved_at: self.autosaved_at,
            autosave_failures: self.autosave_failures.clone(),
            problems: Vec::new(),
            kernels,
            keyframe_reports: self.keyframes.clone(),
        }
    }

    /// The keyframe trajectory, every keyframe of the map (resumed runs
    /// included), camera-to-world.
    pub fn trajectory(&self) -> Vec<(u64, CameraPose)> {
        self.mapper
            .online_ref()
            .trajectory()
            .iter()
            .map(|&(stamp, pose)| (stamp.max(0) as u64, pose))
            .collect()
    }

    /// Writes the run folder `dir`: the resumable state, `map.ply`,
    /// `decoder.safetensors` (when the map has embeddings),
    /// `config.toml`, `trajectory.txt`, `trace.json` (when profiled) and,
    /// last, `report.json`. Every file is replaced whole. What cannot be
    /// written is listed in the report's `problems` (and returned), the
    /// rest is still written: after a GPU failure the window cannot be
    /// read back, so the state file keeps its last save and `map.ply`
    /// holds the map as of the last window sync.
    pub fn write_folder(&mut self, dir: &Path) -> Result<RunReport> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let mut problems = Vec::new();
        let gpu = self.mapper.online().flush();
        match &gpu {
            Ok(()) => {
                if let Err(e) = self.mapper.save(dir) {
                    problems.push(format!("{STATE_FILE} not updated: {e}"));
                }
                let decoder = dir.join(DECODER_FILE);
                match self.mapper.online().decoder_file() {
                    Ok(Some(d)) => {
                        if let Err(e) = d.write(&decoder) {
                            problems.push(format!("{DECODER_FILE} not written: {e}"));
                        }
                    }
                    // A stale decoder from an earlier run must not pair
                    // with this map.
                    Ok(None) => {
                        let _ = std::fs::remove_file(&decoder);
                    }
                    Err(e) => problems.push(format!("{DECODER_FILE} not written: {e}")),
                }
            }
            Err(e) => problems.push(format!(
                "the GPU state could not be read back ({e}): {STATE_FILE} and {DECODER_FILE} \
                 keep their last save{}, map.ply holds the map as of the last window sync",
                self.autosaved_at
                    .map_or(String::new(), |k| format!(" (autosave at keyframe {k})"))
            )),
        }
        let config = format!(
            "# The effective configuration of this run (`latentam map --config` reads it back;\n\
             # `latentam config --print-defaults` documents every key).\n{}",
            self.mapper.online_ref().config().to_toml()
        );
        let mut attempt = |what: &str, r: Result<()>| {
            if let Err(e) = r {
                problems.push(format!("{what} not written: {}", describe(&e)));
            }
        };
        attempt("config.toml", write_text(&dir.join("config.toml"), &config));
        let gaussians: Vec<_> = self.mapper.global().iter().map(|(_, g)| *g).collect();
        attempt(
            "map.ply",
            write_ply(&dir.join("map.ply"), &gaussians, &[]).map_err(Into::into),
        );
        attempt(
            "trajectory.txt",
            write_tum(&dir.join("trajectory.txt"), &self.trajectory()).map_err(Into::into),
        );
        let profile = self.ctx.profiler_snapshot();
        if !profile.samples().is_empty() {
            attempt(
                "trace.json",
                profile
                    .write_chrome_trace(&dir.join("trace.json"))
                    .map_err(Into::into),
            );
        }
        let mut report = self.report_with(profile.stats());
        report.problems = problems;
        write_text(
            &dir.join("report.json"),
            &serde_json::to_string_pretty(&report)?,
        )
        .with_context(|| format!("writing the run report in {}", dir.display()))?;
        Ok(report)
    }
}

/// Writes `text` to `path` whole or not at all.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    Ok(latentam::io::write_bytes_atomically(path, text.as_bytes())?)
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
    let skipped = r.ingest.total_skipped();
    if skipped > 0 {
        s += &format!("input: {skipped} messages or frames skipped (see report.json `ingest`)\n");
    }
    s
}
