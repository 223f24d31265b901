//! Mapping a whole log into a run folder, with autosave and resume: the
//! loop a recording or a robot's log goes through, shared by every client
//! (the `latentam map` command is one).
//!
//! The run folder is replaced whole (see [`RunFolder`](crate::mapper::RunFolder)): every autosave and
//! the final write put a complete, consistent version in place, or leave
//! the previous one. A run that stops early (a stop request, a frame
//! limit, an unreadable frame, a frame refused for its content) still
//! writes what was mapped, with the failure in `report.json`; a failure in
//! the middle of a keyframe, or a run that mapped nothing, leaves the
//! folder as it was.
//!
//! A resumed run skips the frames its saved state mapped already, by
//! timestamp ([`Mapper::already_mapped`](crate::mapper::Mapper::already_mapped)), so a log with a frame more or
//! less than the first time resumes where the map ends.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::handle::LiveMapper;
use super::options::LiveOptions;
use super::reader::LiveReader;
use super::shared::Outcome;
use crate::mapper::{
    Ending, HostWaits, Integrated, KeyframeReport, Mapper, MapperStats, RunFolder, RunReport,
};
use latentam_base::files::write_bytes_atomically;
use latentam_base::{Error, Result};
use latentam_io::{write_tum, AssemblyConfig, CameraPose, IngestReport, McapFrames, McapLog};

/// How [`LogRun::map`] goes through a log.
///
/// ```no_run
/// # fn f() -> latentam_core::Result<()> {
/// use latentam_core::live::LogRunOptions;
/// // The first 500 frames, saving every 10 keyframes.
/// let options = LogRunOptions { max_frames: Some(500), autosave_every: 10, ..Default::default() };
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Debug, Default)]
pub struct LogRunOptions {
    /// Stop after this many frames of the log (those a resumed run skips
    /// included).
    pub max_frames: Option<usize>,
    /// Write the run folder every this many keyframes while mapping (0:
    /// only at the end, by [`LogRun::write_folder`]), so a crash or a lost
    /// device loses at most this many keyframes.
    pub autosave_every: u64,
    /// Keep mapping when an autosave fails (listed in the report's
    /// `autosave_failures`). By default a failed autosave stops the run:
    /// a folder that cannot be written now will not be written at the
    /// end either, and hours of mapping would be lost without a word.
    pub continue_after_failed_autosave: bool,
}

/// What a client sees of a run of a log, and what it adds to it. Every
/// method has a default that does nothing, so `&mut ()` observes nothing.
///
/// ```no_run
/// # fn f() -> latentam_core::Result<()> {
/// use latentam_core::live::RunObserver;
/// use latentam_core::mapper::{KeyframeReport, MapperStats};
/// struct Printer;
/// impl RunObserver for Printer {
///     fn frame_done(&mut self, frames: u64, _: &MapperStats, last: Option<&KeyframeReport>) {
///         if let Some(k) = last {
///             eprintln!("frame {frames}: keyframe {} took {:.0} ms", k.index, k.timings.total_ms);
///         }
///     }
/// }
/// # Ok(())
/// # }
/// ```
pub trait RunObserver {
    /// Before the first frame: the log's frame source (its topic plan, its
    /// vocabulary) and the number of frames the run will go through, when
    /// the log's summary says.
    fn started(&mut self, _frames: &McapFrames, _total: Option<usize>) {}

    /// After each frame of the log, mapped or skipped: how many were gone
    /// through, the mapper's statistics after it, and the last keyframe's
    /// report.
    fn frame_done(&mut self, _frames: u64, _stats: &MapperStats, _last: Option<&KeyframeReport>) {}

    /// Asked before each frame: whether to stop here ([`Ending::Interrupted`]).
    /// A keyframe in progress can be cut short too, through
    /// [`Mapper::set_hurry_flag`](crate::mapper::Mapper::set_hurry_flag).
    fn stop_requested(&mut self) -> bool {
        false
    }

    /// Once mapping starts: a reader of the live map (for a viewer, see
    /// `latentam_view::LiveView`), valid until the run ends.
    fn live_started(&mut self, _reader: &LiveReader) {}

    /// The input looks wrong in a way that does not stop mapping (e.g.
    /// depth in another camera frame than colour): said once per warning,
    /// as soon as it is seen; all are in the report's `ingest.warnings`.
    fn input_warning(&mut self, _warning: &str) {}

    /// An autosave failed; mapping goes on, and the failure is listed in
    /// the report.
    fn autosave_failed(&mut self, _keyframe: u64, _error: &Error) {}

    /// Writes the client's own files into the staged version of the run
    /// folder `dir`, beside the report, before it is swapped in. Each must
    /// be one of [`RUN_FOLDER_FILES`](crate::mapper::RUN_FOLDER_FILES).
    fn write_extra_files(&mut self, _dir: &Path, _report: &RunReport) -> Result<()> {
        Ok(())
    }
}

impl RunObserver for () {}

/// What [`LogRun::write_folder`] did.
///
/// ```no_run
/// # fn f(run: &mut latentam_core::live::LogRun, folder: &latentam_core::mapper::RunFolder) -> latentam_core::Result<()> {
/// use latentam_core::live::Written;
/// match run.write_folder(folder, &mut ())? {
///     Written::Saved(report) => println!("saved {} keyframes", report.keyframes),
///     Written::Kept(why) => eprintln!("folder unchanged: {why}"),
/// }
/// # Ok(())
/// # }
/// ```
#[derive(Debug)]
pub enum Written {
    /// The folder now holds this run, described by the report.
    Saved(Box<RunReport>),
    /// The folder was left as it was, for this reason.
    Kept(Kept),
}

/// Why [`LogRun::write_folder`] left the folder as it was.
///
/// ```no_run
/// # fn f(run: &latentam_core::live::LogRun) -> latentam_core::Result<()> {
/// use latentam_core::live::Kept;
/// if let Some(Kept::NothingMapped(why)) = run.not_to_save() {
///     eprintln!("the log gave no map: {why}");
/// }
/// # Ok(())
/// # }
/// ```
#[derive(Debug, Clone, PartialEq)]
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

/// A finished (or stopped) run of a log.
///
/// ```no_run
/// use latentam_io::AssemblyConfig;
/// use latentam_core::live::{LogRun, LogRunOptions, Written};
/// use latentam_core::mapper::{Mapper, RunFolder, STATE_FILE};
///
/// let ctx = latentam_gpu::Context::new(Default::default())?;
/// let folder = RunFolder::lock("out/run")?;
/// // Continue the map saved there, or start one.
/// let mapper = if folder.dir().join(STATE_FILE).exists() {
///     Mapper::load(&ctx, folder.dir())?
/// } else {
///     Mapper::with_context(&ctx, latentam_core::mapper::MapperConfig::default())?
/// };
/// let options = LogRunOptions { autosave_every: 25, ..Default::default() };
/// let mut run = LogRun::map(
///     mapper,
///     "log.mcap".as_ref(),
///     AssemblyConfig::default(),
///     &options,
///     Some(&folder),
///     &mut (),
/// )?;
/// match run.write_folder(&folder, &mut ())? {
///     Written::Saved(report) => println!("{} keyframes", report.keyframes),
///     Written::Kept(why) => println!("kept as it was: {why}"),
/// }
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct LogRun {
    /// The mapper, holding the map.
    pub mapper: Mapper,
    /// The input log.
    pub log: PathBuf,
    /// Frames offered to the mapper in this run.
    pub frames: u64,
    /// Frames skipped because the resumed state had mapped them.
    pub skipped: u64,
    /// Every keyframe mapped in this run.
    pub keyframes: Vec<KeyframeReport>,
    /// Wall time of this run, seconds.
    pub wall_s: f64,
    /// How it ended.
    pub ending: Ending,
    /// What the log held and what of it was skipped.
    pub ingest: IngestReport,
    /// Keyframe count at the last successful autosave.
    pub autosaved_at: Option<u64>,
    /// Autosaves that failed (mapping went on).
    pub autosave_failures: Vec<String>,
    /// Frames that reached the mapper and were not keyframes.
    pub not_keyframes: u64,
}

/// What a run counts while its mapper is on the live handle's worker:
/// everything of a [`LogRun`] but the mapper.
struct Tally {
    log: PathBuf,
    /// Frames handed to the live handle.
    submitted: u64,
    frames: u64,
    skipped: u64,
    keyframes: Vec<KeyframeReport>,
    autosaved_at: Option<u64>,
    autosave_failures: Vec<String>,
    not_keyframes: u64,
    /// The mapper's statistics after the last frame counted.
    stats: MapperStats,
    /// Outcomes left to count once the worker has stopped.
    pending: Vec<Outcome>,
}

impl Tally {
    fn new(log: &Path) -> Self {
        Tally {
            log: log.to_path_buf(),
            submitted: 0,
            frames: 0,
            skipped: 0,
            keyframes: Vec::new(),
            autosaved_at: None,
            autosave_failures: Vec::new(),
            not_keyframes: 0,
            stats: MapperStats::default(),
            pending: Vec::new(),
        }
    }

    /// Counts what the worker did since the last call, autosaving when a
    /// keyframe makes one due. Returns the ending when a frame failed.
    fn take_outcomes(
        &mut self,
        live: &LiveMapper,
        options: &LogRunOptions,
        folder: Option<&RunFolder>,
        observer: &mut dyn RunObserver,
        frames: &mut McapFrames,
    ) -> Option<Ending> {
        let mut due = false;
        for outcome in live.take_outcomes() {
            let before = self.stats.keyframes;
            if let Some(failed) = self.count(outcome, frames, observer) {
                self.pending.extend(live.take_outcomes());
                return Some(failed);
            }
            let every = options.autosave_every;
            due |= every > 0
                && self.stats.keyframes != before
                && self.stats.keyframes.is_multiple_of(every);
        }
        let folder = folder.filter(|_| due)?;
        // Between frames, with the mapper: what the worker did meanwhile
        // is counted first, so the folder's report and state agree.
        let mut failed = None;
        let submitted = self.submitted;
        let saved = live.lend_owned(|mapper| {
            for outcome in live.take_outcomes() {
                if let Some(f) = self.count(outcome, frames, observer) {
                    failed.get_or_insert(f);
                }
            }
            let n = mapper.stats().keyframes;
            let mut run = std::mem::replace(self, Tally::new(&self.log)).into_run(mapper);
            run.ingest = frames.report().clone();
            let written = run.write_folder(folder, observer);
            let (mapper, tally) = run.into_parts();
            *self = Tally { submitted, ..tally };
            match written {
                Ok(Written::Saved(_)) => self.autosaved_at = Some(n),
                Ok(Written::Kept(_)) => {}
                Err(e) => {
                    observer.autosave_failed(n, &e);
                    self.autosave_failures.push(format!("keyframe {n}: {e}"));
                    if !options.continue_after_failed_autosave {
                        failed.get_or_insert(Ending::Failed(format!(
                            "the autosave at keyframe {n} failed, so the run stops \
                             (--continue-after-failed-autosave maps on): {e}"
                        )));
                    }
                }
            }
            (mapper, ())
        });
        if saved.is_err() {
            // The worker is gone; its outcomes are counted at the end.
            self.pending.extend(live.take_outcomes());
        }
        failed
    }

    /// Hands `frame` to the live handle, waiting for room and counting
    /// what the worker did meanwhile; the ending when the run must stop.
    fn submit(
        &mut self,
        live: &LiveMapper,
        frame: latentam_io::Frame,
        options: &LogRunOptions,
        folder: Option<&RunFolder>,
        observer: &mut dyn RunObserver,
        frames: &mut McapFrames,
    ) -> Option<Ending> {
        let stamp = frame.stamp_ns;
        let mut waiting = frame;
        loop {
            match live.submit_waiting(waiting, Duration::from_millis(50)) {
                Ok(None) => return None,
                Ok(Some(back)) => waiting = back,
                // The worker stopped: its outcome says why.
                Err(Error::Stopped(_)) => return None,
                Err(e) => return Some(Ending::Failed(format!("mapping frame at {stamp} ns: {e}"))),
            }
            if let Some(failed) = self.take_outcomes(live, options, folder, observer, frames) {
                return Some(failed);
            }
            if observer.stop_requested() {
                return Some(Ending::Interrupted);
            }
        }
    }

    /// Waits for the worker to map what is queued, counting (and
    /// autosaving) as it goes; the ending when the run must stop early.
    fn drain(
        &mut self,
        live: &LiveMapper,
        options: &LogRunOptions,
        folder: Option<&RunFolder>,
        observer: &mut dyn RunObserver,
        frames: &mut McapFrames,
    ) -> Option<Ending> {
        while !live.wait_idle(Duration::from_millis(50)) {
            if observer.stop_requested() {
                return Some(Ending::Interrupted);
            }
            if let Some(failed) = self.take_outcomes(live, options, folder, observer, frames) {
                return Some(failed);
            }
        }
        self.take_outcomes(live, options, folder, observer, frames)
    }

    /// Counts one frame's outcome; the ending when it failed.
    fn count(
        &mut self,
        outcome: Outcome,
        frames: &mut McapFrames,
        observer: &mut dyn RunObserver,
    ) -> Option<Ending> {
        let stamp = outcome.frame.stamp_ns;
        frames.recycle(outcome.frame);
        self.stats = outcome.stats;
        let failed = match outcome.result {
            Ok(Integrated::Keyframe(k)) => {
                self.frames += 1;
                self.keyframes.push(*k);
                None
            }
            Ok(Integrated::Skipped) => {
                self.frames += 1;
                self.not_keyframes += 1;
                None
            }
            Err(e) => Some(Ending::Failed(format!("mapping frame at {stamp} ns: {e}"))),
        };
        observer.frame_done(
            self.skipped + self.frames,
            &self.stats,
            self.keyframes.last(),
        );
        failed
    }

    fn into_run(self, mapper: Mapper) -> LogRun {
        LogRun {
            mapper,
            log: self.log,
            frames: self.frames,
            skipped: self.skipped,
            keyframes: self.keyframes,
            wall_s: 0.0,
            ending: Ending::Running,
            ingest: IngestReport::default(),
            autosaved_at: self.autosaved_at,
            autosave_failures: self.autosave_failures,
            not_keyframes: self.not_keyframes,
        }
    }
}

impl LogRun {
    /// Maps the log at `log` with `mapper` (new, or loaded to be
    /// continued), writing the run folder `folder` at every autosave when
    /// given. Errors only when the log cannot be opened; failures
    /// part-way end the run with [`Ending::Failed`]. The final write is
    /// the caller's ([`LogRun::write_folder`]), so it can decide what an
    /// unfinished run is worth.
    ///
    /// ```no_run
    /// # fn f(mapper: latentam_core::mapper::Mapper) -> latentam_core::Result<()> {
    /// use latentam_io::AssemblyConfig;
    /// use latentam_core::live::{LogRun, LogRunOptions};
    /// // No run folder: map only, in memory.
    /// let run = LogRun::map(mapper, "log.mcap".as_ref(), AssemblyConfig::default(),
    ///                       &LogRunOptions::default(), None, &mut ())?;
    /// println!("{} keyframes in {:.1} s", run.keyframes.len(), run.wall_s);
    /// # Ok(())
    /// # }
    /// ```
    pub fn map(
        mapper: Mapper,
        log: &Path,
        assembly: AssemblyConfig,
        options: &LogRunOptions,
        folder: Option<&RunFolder>,
        observer: &mut dyn RunObserver,
    ) -> Result<LogRun> {
        let opened = McapLog::open(log)?;
        let mut frames = McapFrames::from_log(opened.clone(), assembly)?;
        // Colour images bound the frames; the summary says how many there are.
        let in_log = opened
            .message_count(&frames.topics().color)
            .map(|n| n as usize);
        let total = match (in_log, options.max_frames) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        observer.started(&frames, total);
        // A state from before stamps were saved resumes by count.
        let stats = mapper.stats();
        let skip_by_count = match stats.last_frame_stamp_ns {
            Some(_) => 0,
            None => stats.frames,
        };
        let mut mapped_up_to = stats.last_frame_stamp_ns;
        let limit = options.max_frames.unwrap_or(usize::MAX);
        let mut run = Tally::new(log);
        let start = Instant::now();
        // The log goes through the live handle, as a robot's frames would,
        // but nothing is dropped: the reader waits for room, and reads the
        // next frames while the worker maps.
        let live = LiveMapper::start(
            mapper,
            LiveOptions {
                queue_frames: 3,
                stop_on_rejected: true,
                ..LiveOptions::default()
            },
        )?;
        live.record_outcomes();
        observer.live_started(&live.reader());
        let mut warned = 0;
        let mut ending = loop {
            for w in &frames.report().warnings[warned..] {
                observer.input_warning(w);
            }
            warned = frames.report().warnings.len();
            if let Some(failed) = run.take_outcomes(&live, options, folder, observer, &mut frames) {
                break failed;
            }
            if observer.stop_requested() {
                break Ending::Interrupted;
            }
            if (run.skipped + run.submitted) as usize >= limit {
                break Ending::FrameLimit;
            }
            let Some(frame) = frames.next() else {
                break Ending::Complete;
            };
            let frame = match frame {
                Ok(f) => f,
                Err(e) => break Ending::Failed(format!("reading {}: {e}", log.display())),
            };
            let mapped = mapped_up_to.is_some_and(|last| frame.stamp_ns <= last);
            if mapped || run.skipped < skip_by_count {
                run.skipped += 1;
                frames.recycle(frame);
                observer.frame_done(run.skipped + run.frames, &run.stats, None);
                continue;
            }
            mapped_up_to = Some(frame.stamp_ns);
            run.submitted += 1;
            if let Some(ended) = run.submit(&live, frame, options, folder, observer, &mut frames) {
                break ended;
            }
        };
        // A run that read its last frame maps what is queued, counting (and
        // autosaving) as it goes.
        if matches!(ending, Ending::Complete | Ending::FrameLimit) {
            if let Some(ended) = run.drain(&live, options, folder, observer, &mut frames) {
                ending = ended;
            }
        }
        // An interrupted run stops at once (the keyframe in progress hurries
        // through the mapper's hurry flag), dropping what is queued.
        let interrupted = ending == Ending::Interrupted;
        let (mapper, stopped, last) = live.close_keeping_failures(interrupted);
        let mapper = mapper.ok_or_else(|| {
            let why = stopped.map_or("the worker ended".into(), |e| e.to_string());
            Error::Panicked(format!("the mapper was lost: {why}"))
        })?;
        let mut rest = std::mem::take(&mut run.pending);
        rest.extend(last);
        for outcome in rest {
            if let Some(failed) = run.count(outcome, &mut frames, observer) {
                if !matches!(ending, Ending::Failed(_)) {
                    ending = failed;
                }
            }
        }
        let mut run = run.into_run(mapper);
        run.ending = ending;
        run.wall_s = start.elapsed().as_secs_f64();
        run.ingest = frames.report().clone();
        Ok(run)
    }

    /// The mapper and the counts apart (for an autosave while mapping).
    fn into_parts(self) -> (Mapper, Tally) {
        let stats = self.mapper.stats();
        let tally = Tally {
            log: self.log,
            submitted: self.frames,
            frames: self.frames,
            skipped: self.skipped,
            keyframes: self.keyframes,
            autosaved_at: self.autosaved_at,
            autosave_failures: self.autosave_failures,
            not_keyframes: self.not_keyframes,
            stats,
            pending: Vec::new(),
        };
        (self.mapper, tally)
    }

    /// The report of this run, with the profiler's per-kernel statistics,
    /// for the run folder version `run_id`.
    ///
    /// ```no_run
    /// # fn f(run: &latentam_core::live::LogRun) -> latentam_core::Result<()> {
    /// let report = run.report("example-run");
    /// println!("{}", serde_json::to_string_pretty(&report).unwrap());
    /// # Ok(())
    /// # }
    /// ```
    pub fn report(&self, run_id: &str) -> RunReport {
        let kernels = self.mapper.context().profiler_snapshot().stats();
        self.report_with(run_id, kernels)
    }

    fn report_with(
        &self,
        run_id: &str,
        kernels: std::collections::BTreeMap<&'static str, latentam_gpu::KernelStats>,
    ) -> RunReport {
        let stats = self.mapper.stats();
        let t = &stats.timings;
        let ctx = self.mapper.context();
        let calls: Vec<_> = self.keyframes.iter().map(|k| k.gpu_calls).collect();
        RunReport {
            run_id: run_id.to_string(),
            log: self.log.display().to_string(),
            device: ctx.info().name.clone(),
            time_to_ready_ms: ctx.time_to_ready_ms(),
            pipeline_cache_loaded_bytes: ctx.info().pipeline_cache_loaded_bytes,
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
            ms_per_keyframe: t.per_keyframe(stats.keyframes),
            host_waits_per_keyframe: HostWaits::of(&calls),
            paging_hidden_share: match (t.paging_gpu_ms, t.paging_hidden_ms) {
                (Some(g), Some(h)) if g > 0.0 => Some(h / g),
                _ => None,
            },
            dedicated_transfer_queue: ctx.info().dedicated_transfer_queue,
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
    ///
    /// ```no_run
    /// # fn f(run: &latentam_core::live::LogRun) -> latentam_core::Result<()> {
    /// for (stamp_ns, pose) in run.trajectory() {
    ///     println!("{stamp_ns} {:?}", pose.translation);
    /// }
    /// # Ok(())
    /// # }
    /// ```
    pub fn trajectory(&self) -> Vec<(u64, CameraPose)> {
        self.mapper
            .trajectory()
            .iter()
            .map(|&(stamp, pose)| (stamp.max(0) as u64, pose))
            .collect()
    }

    /// Why the run folder must not be replaced by this run, if so.
    ///
    /// ```no_run
    /// # fn f(run: &latentam_core::live::LogRun) -> latentam_core::Result<()> {
    /// match run.not_to_save() {
    ///     Some(why) => eprintln!("not saving: {why}"),
    ///     None => println!("ready to save"),
    /// }
    /// # Ok(())
    /// # }
    /// ```
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
    ///
    /// ```no_run
    /// # fn f(run: &latentam_core::live::LogRun) -> latentam_core::Result<()> {
    /// if run.not_to_save().is_some() {
    ///     eprintln!("{}", run.kept_description());
    /// }
    /// # Ok(())
    /// # }
    /// ```
    pub fn kept_description(&self) -> String {
        match self.autosaved_at {
            Some(k) => format!("its autosave at keyframe {k}"),
            None => "the run it held before, if any".into(),
        }
    }

    /// Why no keyframe (or no Gaussian) came of the log, with counts.
    ///
    /// ```no_run
    /// # fn f(run: &latentam_core::live::LogRun) -> latentam_core::Result<()> {
    /// if run.keyframes.is_empty() {
    ///     eprintln!("no keyframe: {}", run.why_nothing());
    /// }
    /// # Ok(())
    /// # }
    /// ```
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
    /// `config.toml`, `trajectory.txt`, `trace.json` (when profiled),
    /// `report.json` and the observer's own files, all with one run id.
    /// Either every file is written and the folder swapped in whole, or it
    /// is left as it was: kept for [`LogRun::not_to_save`]'s reasons, an
    /// error for a file that could not be written.
    ///
    /// ```no_run
    /// # fn f(run: &mut latentam_core::live::LogRun, folder: &latentam_core::mapper::RunFolder) -> latentam_core::Result<()> {
    /// let written = run.write_folder(folder, &mut ())?;
    /// # Ok(())
    /// # }
    /// ```
    pub fn write_folder(
        &mut self,
        folder: &RunFolder,
        observer: &mut dyn RunObserver,
    ) -> Result<Written> {
        if let Some(why) = self.not_to_save() {
            return Ok(Written::Kept(why));
        }
        let staging = folder.stage()?;
        let dir = staging.path().to_path_buf();
        self.mapper.save_into(&staging)?;
        let config = format!(
            "# The effective configuration of this run (`latentam map --config` and\n\
             # `MapperConfig::from_toml` read it back; `latentam config --print-defaults`\n\
             # documents every key).\n{}",
            self.mapper.config().to_toml()
        );
        write_bytes_atomically(&dir.join("config.toml"), config.as_bytes())?;
        self.mapper.export_ply(&dir.join("map.ply"))?;
        write_tum(&dir.join("trajectory.txt"), &self.trajectory())?;
        let profile = self.mapper.context().profiler_snapshot();
        if !profile.samples().is_empty() {
            profile.write_chrome_trace(&dir.join("trace.json"))?;
        }
        let report = self.report_with(staging.run_id(), profile.stats());
        let path = dir.join("report.json");
        let json = serde_json::to_vec_pretty(&report).map_err(|e| Error::Io {
            path: path.clone(),
            source: e.into(),
        })?;
        write_bytes_atomically(&path, &json)?;
        observer.write_extra_files(&dir, &report)?;
        staging.commit()?;
        Ok(Written::Saved(Box::new(report)))
    }
}
