//! Mapping a log for `latentam map`, `profile` and `demo`: the library's
//! [`LogRun`] with the CLI's status line, Ctrl-C handling and
//! `report.html`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context as _, Result};
use latentam::frames::{AssemblyConfig, McapFrames};
use latentam::runs::{RunFolder, Written, DECODER_FILE, STATE_FILE};
use latentam::text::shown;
use latentam::{
    Config as MapperConfig, Context, ContextOptions, KeyframeReport, LiveReader, LogRun,
    LogRunOptions, Mapper, MapperStats, RunObserver, RunReport,
};

use crate::interrupt;
use latentam_cli::progress::StatusLine;

/// What to map.
pub struct RunOptions {
    /// The input log.
    pub log: PathBuf,
    /// How its messages become frames.
    pub assembly: AssemblyConfig,
    /// The effective configuration (ignored when resuming: the saved
    /// state's shape-defining settings win, see `Mapper::load_with`).
    pub config: MapperConfig,
    /// Stop after this many frames of the log.
    pub max_frames: Option<usize>,
    /// Continue the state saved in the run folder, with these settings
    /// applied over its own.
    pub resume: Option<crate::config_args::ConfigArgs>,
    /// Time every kernel (for `trace.json` and the profile table).
    pub profile: bool,
    /// Write the run folder every this many keyframes while mapping (0:
    /// only at the end).
    pub autosave_every: u64,
    /// See `LogRunOptions::continue_after_failed_autosave`.
    pub continue_after_failed_autosave: bool,
    /// Serve a live view while mapping.
    pub live: Option<crate::live_args::LiveViewArgs>,
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

    fn update(&mut self, frames: u64, stats: &MapperStats, last_report: Option<&KeyframeReport>) {
        if !self.line.due() {
            return;
        }
        let elapsed = self.start.elapsed().as_secs_f64().max(1e-9);
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

/// Builds every kernel `mapper` can dispatch, with a status line
/// "building kernels (n of N)" once it takes more than a second: on a
/// machine whose driver has never compiled them, that is tens of seconds.
fn build_kernels(mapper: &Mapper) -> Result<()> {
    let start = Instant::now();
    let mut line = StatusLine::default();
    let mut shown = false;
    mapper.warm_up_reporting(|built, of| {
        let waited = start.elapsed().as_secs_f64();
        if (waited >= 1.0 && line.due()) || (shown && built == of) {
            line.show(&format!(
                "building kernels ({built} of {of}) · {waited:.0} s"
            ));
            shown = true;
        }
    })?;
    if shown {
        line.finish();
    }
    Ok(())
}

/// Maps `opts.log` through the library's [`LogRun`], writing the run
/// folder `folder` at every autosave (when given), with a status line,
/// Ctrl-C handling and `report.html` beside the report; errors only when
/// nothing could start (no device, an unreadable log or state). Failures
/// part-way end the run with [`Ending::Failed`]. The final write is the
/// caller's ([`write_folder`]).
pub fn map_log(opts: &RunOptions, folder: Option<&RunFolder>) -> Result<LogRun> {
    let ctx = Context::new(ContextOptions {
        profiling: opts.profile,
        ..ContextOptions::default()
    })?;
    let mapper = match (folder, &opts.resume) {
        (Some(folder), Some(settings)) => {
            let settings = |saved: &MapperConfig| {
                settings.load_over(saved.clone()).map_err(|e| {
                    // The library's own error as it is; one with context
                    // (the --config file it came from) keeps the context.
                    let (text, links) = (format!("{e:#}"), e.chain().count());
                    match e.downcast::<latentam::Error>() {
                        Ok(e) if links == 1 => e,
                        _ => latentam::Error::config("--config", text),
                    }
                })
            };
            Mapper::load_with(&ctx, folder.dir(), &settings)
                .with_context(|| format!("loading the saved state in {}", folder.dir().display()))?
        }
        _ => Mapper::with_context(&ctx, opts.config.clone())?,
    };
    build_kernels(&mapper)?;
    // Profile the mapping, not the warm-up or the load.
    ctx.profiler_reset();
    interrupt::install();
    let mut observer = CliObserver {
        live: opts.live.clone(),
        log: opts.log.clone(),
        ..CliObserver::default()
    };
    let run = LogRun::map(
        mapper,
        &opts.log,
        opts.assembly.clone(),
        &LogRunOptions {
            max_frames: opts.max_frames,
            autosave_every: opts.autosave_every,
            continue_after_failed_autosave: opts.continue_after_failed_autosave,
            hurry: Some(interrupt::flag()),
        },
        folder,
        &mut observer,
    )
    .with_context(|| format!("opening {}", opts.log.display()));
    if let Some(progress) = &observer.progress {
        progress.finish();
    }
    if let Some(view) = observer.view.take() {
        let port = view.port();
        let stats = view.close();
        eprintln!(
            "live view (port {port}): {} publications, {} messages, {:.1} MB sent",
            stats.publications,
            stats.messages,
            stats.bytes as f64 / 1e6
        );
    }
    if let Some(e) = observer.error.take() {
        return Err(e);
    }
    run
}

/// Replaces the run folder with `run` (see [`LogRun::write_folder`]), with
/// `report.html` beside `report.json`.
pub fn write_folder(run: &mut LogRun, folder: &RunFolder) -> Result<Written> {
    Ok(run.write_folder(folder, &mut CliObserver::default())?)
}

/// The CLI's view of a run: a status line, Ctrl-C, autosave warnings and
/// `report.html`.
#[derive(Default)]
struct CliObserver {
    progress: Option<MapProgress>,
    /// The live view asked for, its options once the log's vocabulary is
    /// known, and the view once mapping started.
    live: Option<crate::live_args::LiveViewArgs>,
    log: PathBuf,
    view_options: Option<latentam::view::ViewOptions>,
    view: Option<latentam::view::LiveView>,
    /// What stopped the run before its first frame.
    error: Option<anyhow::Error>,
}

impl RunObserver for CliObserver {
    fn started(&mut self, frames: &McapFrames, total: Option<usize>) {
        for line in frames.topic_plan() {
            eprintln!("input: {}", shown(&line.to_string()));
        }
        if let Some(live) = &self.live {
            // The log's vocabulary is read before its first frame when the
            // log has one (its message may come later in the log).
            let vocabulary = frames.vocabulary().cloned().or_else(|| {
                latentam::frames::read_vocabulary(&self.log, &frames.topics().vocabulary)
                    .ok()
                    .flatten()
            });
            match live.options(vocabulary.as_ref()) {
                Ok(options) => self.view_options = options,
                Err(e) => self.error = Some(e),
            }
        }
        self.progress = Some(MapProgress::new(total));
    }

    fn live_started(&mut self, reader: &LiveReader) {
        let Some(options) = self.view_options.take() else {
            return;
        };
        let listen = options.listen;
        match latentam::view::LiveView::serve(reader.clone(), options) {
            Ok(view) => {
                eprintln!(
                    "live view: ws://{}:{} (Foxglove: Open connection)",
                    listen.ip(),
                    view.port()
                );
                self.view = Some(view);
            }
            Err(e) => self.error = Some(e.into()),
        }
    }

    fn frame_done(&mut self, frames: u64, stats: &MapperStats, last: Option<&KeyframeReport>) {
        if let Some(progress) = &mut self.progress {
            progress.update(frames, stats, last);
        }
    }

    fn stop_requested(&mut self) -> bool {
        self.error.is_some() || interrupt::requested()
    }

    fn input_warning(&mut self, warning: &str) {
        eprintln!("warning: {}", shown(warning));
    }

    fn autosave_failed(&mut self, keyframe: u64, error: &latentam::Error) {
        eprintln!(
            "warning: autosave at keyframe {keyframe} failed: {}",
            shown(&latentam::text::with_causes(error))
        );
    }

    fn write_extra_files(&mut self, dir: &Path, report: &RunReport) -> latentam::Result<()> {
        latentam_report::write_report_html(dir, report)
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
    if let Some(ready) = r.time_to_ready_ms {
        let cache = match r.pipeline_cache_loaded_bytes {
            0 => "no compiled pipelines cached".to_string(),
            n => format!(
                "{:.1} MB of compiled pipelines from the cache",
                n as f64 / 1e6
            ),
        };
        let b = &r.kernel_builds;
        let built = match b.slowest.first() {
            Some((name, ms)) => format!(
                "{} kernels built, {:.1} s of work, the slowest {name} {:.1} s",
                b.kernels,
                b.work_ms / 1e3,
                ms / 1e3
            ),
            None => "no kernel to build".to_string(),
        };
        s += &format!(
            "ready for the first frame after {ready:.0} ms ({built}; {cache}; not counted below)\n"
        );
    }
    if let Some(first) = r.first_keyframe_over_median {
        s += &format!("first keyframe: {first:.2}x the median of the next five\n");
    }
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
    s += &r.gpu_work.summary();
    s.push('\n');
    let skipped = r.ingest.total_skipped();
    if skipped > 0 {
        s += &format!("input: {skipped} messages or frames skipped (see report.json `ingest`)\n");
    }
    for n in &r.ingest.notes {
        s += &format!("input: {n}\n");
    }
    for w in &r.ingest.warnings {
        s += &format!("input warning: {w}\n");
    }
    s
}
