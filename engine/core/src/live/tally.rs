//! What a log run counts while its mapper is on the live handle's worker:
//! frames submitted, skipped and mapped, keyframes, autosaves, and the
//! outcomes still to count when the worker stops.

use std::path::{Path, PathBuf};
use std::time::Duration;

use super::handle::LiveMapper;
use super::log_run_types::{LogRun, LogRunOptions, RunObserver, Written};
use super::shared::Outcome;
use crate::mapper::{Ending, Integrated, KeyframeReport, Mapper, MapperStats, RunFolder};
use latentam_base::{Error, Result};
use latentam_io::{IngestReport, McapFrames};

/// What a run counts while its mapper is on the live handle's worker:
/// everything of a [`LogRun`] but the mapper.
pub(super) struct Tally {
    pub(super) log: PathBuf,
    /// Frames handed to the live handle.
    pub(super) submitted: u64,
    pub(super) frames: u64,
    pub(super) skipped: u64,
    pub(super) keyframes: Vec<KeyframeReport>,
    pub(super) autosaved_at: Option<u64>,
    pub(super) autosave_failures: Vec<String>,
    pub(super) not_keyframes: u64,
    /// The mapper's statistics after the last frame counted.
    pub(super) stats: MapperStats,
    /// Outcomes left to count once the worker has stopped.
    pub(super) pending: Vec<Outcome>,
}

impl Tally {
    pub(super) fn new(log: &Path) -> Self {
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
    pub(super) fn take_outcomes(
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
    pub(super) fn submit(
        &mut self,
        live: &LiveMapper,
        frame: latentam_io::Frame,
        options: &LogRunOptions,
        folder: Option<&RunFolder>,
        observer: &mut dyn RunObserver,
        frames: &mut McapFrames,
    ) -> Option<Ending> {
        let stamp = frame.stamp_ns;
        // Checked once, not each time it is given back for want of room.
        if let Err(e) = frame.check() {
            return Some(Ending::Failed(format!("mapping frame at {stamp} ns: {e}")));
        }
        let mut waiting = frame;
        loop {
            match live.submit_checked_waiting(waiting, Duration::from_millis(50)) {
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
    pub(super) fn drain(
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
    pub(super) fn count(
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

    /// Closes the live handle and counts the outcomes it still held: the
    /// run as it ended (a failure among them is the ending, unless the
    /// run had failed already). An interrupted run stops at once (the
    /// keyframe in progress hurries through the mapper's hurry flag),
    /// dropping what is queued.
    pub(super) fn close(
        mut self,
        live: LiveMapper,
        mut ending: Ending,
        frames: &mut McapFrames,
        observer: &mut dyn RunObserver,
    ) -> Result<LogRun> {
        let interrupted = ending == Ending::Interrupted;
        let (mapper, stopped, last) = live.close_keeping_failures(interrupted);
        let mapper = mapper.ok_or_else(|| {
            let why = stopped.map_or("the worker ended".into(), |e| e.to_string());
            Error::Panicked(format!("the mapper was lost: {why}"))
        })?;
        let mut rest = std::mem::take(&mut self.pending);
        rest.extend(last);
        for outcome in rest {
            if let Some(failed) = self.count(outcome, frames, observer) {
                if !matches!(ending, Ending::Failed(_)) {
                    ending = failed;
                }
            }
        }
        let mut run = self.into_run(mapper);
        run.ending = ending;
        Ok(run)
    }

    pub(super) fn into_run(self, mapper: Mapper) -> LogRun {
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
