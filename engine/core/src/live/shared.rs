//! What the handle, the worker and the indexer share: the queue, the
//! loans of the mapper, the counters, and the snapshots.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{mpsc, Arc, Condvar, Mutex, MutexGuard, RwLock};
use std::time::Instant;

use latentam_base::Error;
use latentam_io::Frame;

use super::keyframe_image::KeyframeImage;
use super::options::LiveOptions;
use super::queue::{DropCounts, FrameQueue};
use crate::mapper::MapSnapshot;
use crate::mapper::{Integrated, Mapper};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Close {
    Finish,
    Abort,
}

/// A loan of the mapper; dropping it gives the mapper back.
pub(super) struct Lent {
    pub mapper: Option<Mapper>,
    pub back: mpsc::Sender<Mapper>,
}

impl Drop for Lent {
    fn drop(&mut self) {
        if let Some(m) = self.mapper.take() {
            let _ = self.back.send(m);
        }
    }
}

/// What became of one frame (for [`LogRun`](super::LogRun)).
pub(crate) struct Outcome {
    pub frame: Frame,
    pub result: std::result::Result<Integrated, Arc<Error>>,
    /// The mapper's statistics after it.
    pub stats: crate::mapper::MapperStats,
}

pub(super) struct State {
    pub queue: FrameQueue,
    pub lends: VecDeque<mpsc::Sender<Lent>>,
    pub close: Option<Close>,
    pub busy: bool,
    pub exited: bool,
    pub submitted: u64,
    pub integrated: u64,
    pub keyframes: u64,
    pub dropped: DropCounts,
    pub last_latency_ms: Option<f64>,
    pub last_stamp_latency_ms: Option<f64>,
    pub last_keyframe_ms: Option<f64>,
    pub recent: VecDeque<Instant>,
    pub last_error: Option<Arc<Error>>,
    pub stopped: Option<Arc<Error>>,
    /// The worker stopped on a failure that left no usable map.
    pub fatal: bool,
    pub wants_index: bool,
    /// A reader waits for a snapshot newer than the last one taken.
    pub snapshot_wanted: bool,
    /// Keyframes mapped through the handle when the last snapshot was
    /// taken (it is current while this equals `keyframes`).
    pub published: u64,
    /// Snapshots taken by the worker.
    pub snapshots: u64,
    /// Gaussians in the map and the GPU bytes it held after the last
    /// keyframe (or when the handle started).
    pub gaussians: usize,
    pub gpu_bytes: u64,
    pub outcomes: Option<Vec<Outcome>>,
    /// Reports of the keyframes not taken yet, when the options keep them.
    pub keyframe_reports: Option<Vec<crate::mapper::KeyframeReport>>,
}

pub(super) struct Shared {
    pub state: Mutex<State>,
    /// Wakes the worker: a frame, a loan, a snapshot wanted, a close.
    pub work: Condvar,
    /// Wakes callers: room in the queue, a frame done, a snapshot taken,
    /// the worker gone.
    pub room: Condvar,
    /// Wakes the indexer: a snapshot, a first query, a close.
    pub index_wake: Condvar,
    pub snapshot: RwLock<Arc<MapSnapshot>>,
    /// The last keyframe's image and camera.
    pub last_keyframe: RwLock<Option<Arc<KeyframeImage>>>,
    /// The newest snapshot whose relevance index is built.
    pub indexed: RwLock<Option<Arc<MapSnapshot>>>,
    pub stop: Arc<AtomicBool>,
    /// Set when the handle closes: the indexer gives up its build.
    pub closing: AtomicBool,
    /// Live [`LiveReader`](super::LiveReader)s, the handle's own included.
    pub readers: AtomicUsize,
    pub options: LiveOptions,
    pub ready_ms: Option<f64>,
}

impl Shared {
    pub fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub fn latest(&self) -> Arc<MapSnapshot> {
        self.snapshot
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    pub fn fail(&self, e: Error, fatal: bool) {
        self.fail_shared(Arc::new(e), fatal)
    }

    pub fn fail_shared(&self, e: Arc<Error>, fatal: bool) {
        let mut st = self.lock();
        st.fatal |= fatal;
        st.last_error = Some(e.clone());
        st.stopped.get_or_insert(e);
    }

    pub fn exit(&self) {
        let mut st = self.lock();
        st.exited = true;
        // A reader that asked for a loan after the worker's last look at
        // the queue gets `Stopped` rather than waiting forever.
        st.lends.clear();
        drop(st);
        self.room.notify_all();
        self.index_wake.notify_all();
    }

    pub fn stopped_error(&self) -> Error {
        self.lock().stopped_error()
    }

    /// Asks the worker and the indexer to end; an abort (which wins over
    /// a finish) also hurries the keyframe in progress.
    pub fn ask_to_close(&self, how: Close) {
        {
            let mut st = self.lock();
            if st.close != Some(Close::Abort) {
                st.close = Some(how);
            }
        }
        if how == Close::Abort {
            self.stop.store(true, Ordering::SeqCst);
        }
        self.closing.store(true, Ordering::SeqCst);
        self.work.notify_all();
        self.index_wake.notify_all();
        // Readers waiting for a snapshot give up on an abort.
        self.room.notify_all();
    }

    /// Waits (on `room`) until `done` holds: the guard.
    pub fn wait_for(&self, done: impl Fn(&State) -> bool) -> MutexGuard<'_, State> {
        let mut st = self.lock();
        while !done(&st) {
            st = self.room.wait(st).unwrap_or_else(|e| e.into_inner());
        }
        st
    }

    /// Waits (on `room`) until `done` holds or `deadline` passes: the
    /// guard, and whether `done` holds.
    pub fn wait_until(
        &self,
        deadline: Instant,
        done: impl Fn(&State) -> bool,
    ) -> (MutexGuard<'_, State>, bool) {
        let mut st = self.lock();
        loop {
            if done(&st) {
                return (st, true);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return (st, false);
            }
            st = self
                .room
                .wait_timeout(st, left)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }
}

impl State {
    /// Whether the newest snapshot shows every keyframe mapped so far.
    pub fn snapshot_current(&self) -> bool {
        self.published >= self.keyframes
    }

    /// Counts a snapshot the worker tried to take of the map after
    /// `keyframes` (`taken`: it succeeded; a failure while mapping stopped
    /// the worker, which also ends the wait of any reader).
    pub fn record_snapshot(&mut self, taken: bool, keyframes: u64) {
        if taken {
            self.published = keyframes;
            self.snapshots += 1;
        }
        self.snapshot_wanted = false;
    }

    /// Whether the worker should take a snapshot before anything else:
    /// a reader waits for one, and the map can give one.
    pub fn snapshot_due(&self) -> bool {
        self.snapshot_wanted && !self.snapshot_current() && !self.fatal
    }

    /// What a call on a handle whose worker stopped returns.
    pub fn stopped_error(&self) -> Error {
        let cause = self.stopped.clone().unwrap_or_else(|| {
            Arc::new(Error::bad_input("the live mapper", "its worker has ended"))
        });
        Error::Stopped(cause)
    }
}
