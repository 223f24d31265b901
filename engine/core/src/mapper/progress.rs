//! Where a map stands in its stream: frames and keyframes counted, the
//! last stamp integrated (where a resumed run goes on), the run folder
//! version it came from, whether a keyframe failed part-way, the summed
//! statistics, and the flags that ask a keyframe in progress to hurry.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use super::keyframe_report::{MapperStats, PagingReport};
use latentam_base::{Error, Result};

/// Counters and flags of a map.
#[derive(Default)]
pub(crate) struct Progress {
    /// Frames whose step completed.
    frames: u64,
    /// Stamp of the last frame integrated.
    last_stamp_ns: Option<i64>,
    /// Counts and summed timings over the run.
    stats: MapperStats,
    /// The run folder version the state was loaded from.
    run_id: Option<String>,
    /// A keyframe step failed after it had changed the map: the state is
    /// neither the one before that frame nor the one after it, so it is
    /// neither saved nor mapped further.
    broken: Option<String>,
    /// Set by the caller to have the keyframe in progress skip its
    /// remaining optimisation steps.
    hurry: Option<&'static AtomicBool>,
    /// The same, set by a live handle's `abort`.
    stop: Arc<AtomicBool>,
}

/// The running counters a saved state keeps.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Counters {
    pub frames: u64,
    pub keyframes: u64,
    pub evicted: u64,
    pub fetched: u64,
    pub over_capacity: u64,
    /// Stamp of the last frame integrated (absent in states written before
    /// it was kept).
    pub last_stamp_ns: Option<i64>,
}

impl Counters {
    /// Whether frames were mapped without the last one's stamp kept. The
    /// one definition of "has no stamp" that the reader and the writer of
    /// a saved state share (see `persist::missing_from`).
    pub fn stamp_missing(&self) -> bool {
        self.frames > 0 && self.last_stamp_ns.is_none()
    }
}

impl Progress {
    /// A loaded state's counters and run id.
    pub(crate) fn restored(counters: Counters, run_id: Option<String>) -> Self {
        let mut p = Progress {
            frames: counters.frames,
            last_stamp_ns: counters.last_stamp_ns,
            run_id,
            ..Progress::default()
        };
        p.stats.keyframes = counters.keyframes;
        p.stats.evicted = counters.evicted;
        p.stats.fetched = counters.fetched;
        p.stats.over_capacity = counters.over_capacity;
        p
    }

    /// The counters a save keeps.
    pub(crate) fn counters(&self) -> Counters {
        Counters {
            frames: self.frames,
            keyframes: self.stats.keyframes,
            evicted: self.stats.evicted,
            fetched: self.stats.fetched,
            over_capacity: self.stats.over_capacity,
            last_stamp_ns: self.last_stamp_ns,
        }
    }

    /// Keyframes mapped.
    pub(crate) fn keyframes(&self) -> u64 {
        self.stats.keyframes
    }

    /// A frame's step completed.
    pub(crate) fn count_frame(&mut self, stamp_ns: i64) {
        self.frames += 1;
        self.last_stamp_ns = Some(stamp_ns);
    }

    /// A keyframe at `stamp_ns` starts changing the map: until
    /// [`Progress::keyframe_done`] the map is inconsistent.
    pub(crate) fn keyframe_started(&mut self, stamp_ns: i64) {
        self.broken = Some(format!("keyframe at {stamp_ns} ns"));
    }

    /// The keyframe started last completed.
    pub(crate) fn keyframe_done(&mut self, stamp_ns: i64) {
        self.broken = None;
        self.count_frame(stamp_ns);
    }

    /// A keyframe's work is added to the run's: it counts as mapped from
    /// here on (pruning's interval counts it).
    pub(crate) fn keyframe_trained(&mut self) {
        self.stats.keyframes += 1;
    }

    /// Adds a keyframe's paging to the run's counts.
    pub(crate) fn count_paging(&mut self, paging: &[PagingReport]) {
        for p in paging {
            self.stats.evicted += p.evicted as u64;
            self.stats.fetched += p.fetched as u64;
            self.stats.over_capacity += p.over_capacity as u64;
        }
    }

    /// The summed statistics, to add a keyframe's timings and work to.
    pub(crate) fn stats_mut(&mut self) -> &mut MapperStats {
        &mut self.stats
    }

    /// The statistics with the frame counters filled in.
    pub(crate) fn stats(&self) -> MapperStats {
        let mut s = self.stats.clone();
        s.frames = self.frames;
        s.last_frame_stamp_ns = self.last_stamp_ns;
        s
    }

    /// The id of the run folder version the state was loaded from.
    pub(crate) fn run_id(&self) -> Option<&str> {
        self.run_id.as_deref()
    }

    /// Whether a keyframe step failed part-way.
    pub(crate) fn is_broken(&self) -> bool {
        self.broken.is_some()
    }

    /// Refuses to go on from a keyframe that failed part-way.
    pub(crate) fn check_consistent(&self) -> Result<()> {
        match &self.broken {
            None => Ok(()),
            // Stopped: nothing but a reload goes on from here.
            Some(why) => Err(Error::Stopped(std::sync::Arc::new(Error::bad_input(
                "the map",
                format!(
                    "it is in the middle of a keyframe that failed ({why}); it cannot be saved \
                     or mapped further: load the last save instead"
                ),
            )))),
        }
    }

    /// Has the caller's `flag` hurry keyframes in progress.
    pub(crate) fn set_hurry_flag(&mut self, flag: &'static AtomicBool) {
        self.hurry = Some(flag);
    }

    /// The mapper's own hurry flag, for a live handle's `abort`.
    pub(crate) fn stop_flag(&self) -> Arc<AtomicBool> {
        self.stop.clone()
    }

    /// Whether either hurry flag is set.
    pub(crate) fn hurried(&self) -> bool {
        self.hurry.is_some_and(|f| f.load(Ordering::SeqCst)) || self.stop.load(Ordering::SeqCst)
    }
}
