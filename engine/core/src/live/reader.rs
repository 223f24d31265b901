//! Reading a live map from any thread: [`LiveReader`], a cloneable view
//! of a [`LiveMapper`](super::LiveMapper) for planners and viewers, and
//! what it answers.

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use latentam_base::{Error, Result};

use super::keyframe_image::KeyframeImage;
use super::queue::DropCounts;
use super::shared::{Close, Shared};
use crate::latent::TextQuery;
use crate::mapper::MapSnapshot;
use crate::mapper::Mapper;
use crate::splat::{Camera, RenderedView};

/// Where a [`LiveMapper`](super::LiveMapper) stands.
///
/// ```no_run
/// # fn f(live: &latentam_core::live::LiveMapper) {
/// let s = live.status();
/// println!(
///     "{} queued, {} dropped, last keyframe {:?} ms after submission, {:?} keyframes/s",
///     s.queued_frames, s.dropped.total(), s.last_keyframe_latency_ms, s.keyframes_per_s
/// );
/// if let Some(e) = &s.last_error {
///     eprintln!("last error: {e}");
/// }
/// # }
/// ```
#[derive(Clone, Debug, Default)]
pub struct LiveStatus {
    /// Frames waiting for the worker.
    pub queued_frames: usize,
    /// Their bytes.
    pub queued_bytes: u64,
    /// Frames submitted to this handle.
    pub submitted: u64,
    /// Frames the mapper went through (keyframes, skipped and refused).
    pub integrated: u64,
    /// Keyframes mapped through this handle.
    pub keyframes: u64,
    /// Gaussians in the map after the last keyframe.
    pub gaussians: usize,
    /// GPU memory the mapper held after the last keyframe, bytes.
    pub gpu_bytes: u64,
    /// Snapshots the worker took: for readers (see [`LiveReader::snapshot`])
    /// and every [`LiveOptions::snapshot_every`](super::LiveOptions::snapshot_every) keyframes.
    pub snapshots: u64,
    /// Frames given up, by reason.
    pub dropped: DropCounts,
    /// Whether a frame is being mapped now.
    pub mapping: bool,
    /// The last keyframe's time from `submit` to the end of its mapping
    /// (and its snapshot, when one was taken with it), ms.
    pub last_keyframe_latency_ms: Option<f64>,
    /// The same from the frame's stamp, when the stamp is wall-clock time
    /// (a live camera's; not a log's), ms.
    pub last_keyframe_stamp_latency_ms: Option<f64>,
    /// The last keyframe's mapping time, ms.
    pub last_keyframe_ms: Option<f64>,
    /// Keyframes per second over the last ten.
    pub keyframes_per_s: Option<f64>,
    /// The last error: a refused frame, or what stopped the worker.
    pub last_error: Option<Arc<Error>>,
    /// What stopped the worker, if it stopped: no frame is taken since.
    pub stopped: Option<Arc<Error>>,
    /// Time from the start of [`LiveMapper::new`](super::LiveMapper::new) to a mapper with every
    /// kernel compiled, ms (absent for [`LiveMapper::start`](super::LiveMapper::start)).
    pub ready_ms: Option<f64>,
}

/// An answer to a relevance query, with the snapshot it was computed on
/// (so positions and scores are of the same map).
///
/// ```no_run
/// # fn f(live: &latentam_core::live::LiveMapper, q: &latentam_core::latent::TextQuery) -> latentam_core::Result<()> {
/// let answer = live.relevance(q)?;
/// assert_eq!(answer.scores.len(), answer.snapshot.gaussians.means.len());
/// # Ok(())
/// # }
/// ```
pub struct Relevance {
    /// One relevance per Gaussian of `snapshot`, in its order.
    pub scores: Vec<f32>,
    /// The snapshot scored.
    pub snapshot: Arc<MapSnapshot>,
}

/// Reads a live map from any thread, while it is being mapped: status,
/// snapshots, relevance, renders and saves. Cloning it is cheap; every
/// clone reads the same map. It cannot submit frames or close the
/// mapper, so a viewer or a planner can hold one without owning the
/// mapping.
///
/// ```no_run
/// # fn f(live: &latentam_core::live::LiveMapper) {
/// use std::time::Duration;
/// let reader = live.reader();
/// std::thread::spawn(move || {
///     let mut seen = 0;
///     // Wakes after each keyframe (or each second), as a viewer would.
///     while reader.is_running() {
///         seen = reader.wait_for_keyframe(seen, Duration::from_secs(1));
///         println!("{} Gaussians", reader.snapshot().len());
///     }
/// });
/// # }
/// ```
pub struct LiveReader {
    pub(super) shared: Arc<Shared>,
}

impl LiveReader {
    /// The handle's own reader (the first one).
    pub(super) fn first(shared: Arc<Shared>) -> Self {
        shared.readers.fetch_add(1, Ordering::SeqCst);
        LiveReader { shared }
    }
}

// Counted, so that the worker knows when a reader outlives the handle.
impl Clone for LiveReader {
    fn clone(&self) -> Self {
        Self::first(self.shared.clone())
    }
}

impl Drop for LiveReader {
    fn drop(&mut self) {
        self.shared.readers.fetch_sub(1, Ordering::SeqCst);
    }
}

impl LiveReader {
    /// Where mapping stands: the queue, drops, latencies, errors.
    pub fn status(&self) -> LiveStatus {
        let st = self.shared.lock();
        let keyframes_per_s = match (st.recent.front(), st.recent.back()) {
            (Some(a), Some(b)) if st.recent.len() > 1 => {
                Some((st.recent.len() - 1) as f64 / (*b - *a).as_secs_f64().max(1e-9))
            }
            _ => None,
        };
        LiveStatus {
            queued_frames: st.queue.len(),
            queued_bytes: st.queue.bytes(),
            submitted: st.submitted,
            integrated: st.integrated,
            keyframes: st.keyframes,
            gaussians: st.gaussians,
            gpu_bytes: st.gpu_bytes,
            snapshots: st.snapshots,
            dropped: st.dropped,
            mapping: st.busy,
            last_keyframe_latency_ms: st.last_latency_ms,
            last_keyframe_stamp_latency_ms: st.last_stamp_latency_ms,
            last_keyframe_ms: st.last_keyframe_ms,
            keyframes_per_s,
            last_error: st.last_error.clone(),
            stopped: st.stopped.clone(),
            ready_ms: self.shared.ready_ms,
        }
    }

    /// The map as of the last keyframe mapped (or the map the handle
    /// started with). Snapshots are taken when read: when the newest one
    /// is older than the last keyframe, the worker takes one before its
    /// next frame and this waits for it (at most the rest of the frame in
    /// progress and the copy). A map nobody reads costs no copies; see
    /// [`LiveReader::latest_snapshot`] for one that never waits, and
    /// [`LiveOptions::snapshot_every`](super::LiveOptions::snapshot_every)
    /// to take them whether read or not.
    pub fn snapshot(&self) -> Arc<MapSnapshot> {
        let target = self.ask_for_snapshot();
        // Not after an abort: the worker may be stuck on a GPU that
        // stopped answering, and the handle's drop gives up on it.
        drop(self.shared.wait_for(|st| {
            st.published >= target || st.exited || st.fatal || st.close == Some(Close::Abort)
        }));
        self.shared.latest()
    }

    /// The newest snapshot taken, at once: it may be older than the last
    /// keyframe. It also asks the worker for a fresh one after the frame
    /// in progress, so a reader that polls it sees each keyframe's map
    /// about one keyframe late, and a map nobody reads costs nothing.
    pub fn latest_snapshot(&self) -> Arc<MapSnapshot> {
        self.ask_for_snapshot();
        self.shared.latest()
    }

    /// Asks the worker for a snapshot of the last keyframe when the
    /// newest one is older; returns the keyframes it will show.
    fn ask_for_snapshot(&self) -> u64 {
        let mut st = self.shared.lock();
        let target = st.keyframes;
        if !st.snapshot_current() && !st.snapshot_wanted {
            st.snapshot_wanted = true;
            drop(st);
            self.shared.work.notify_one();
        }
        target
    }

    /// Relevance of every Gaussian to `query`, from the newest snapshot
    /// whose relevance index is built. From the first query on, an
    /// indexer thread indexes each new snapshot, so later queries do not
    /// pay for it; the first one takes a snapshot of the last keyframe (as
    /// [`LiveReader::snapshot`]) and builds its index on the calling
    /// thread. Each query asks for a fresh snapshot (as
    /// [`LiveReader::latest_snapshot`]), so that queries asked after every
    /// keyframe are answered from the map at most a keyframe or two old.
    pub fn relevance(&self, query: &TextQuery) -> Result<Relevance> {
        {
            let mut st = self.shared.lock();
            if !st.wants_index {
                st.wants_index = true;
                self.shared.index_wake.notify_all();
            }
        }
        self.ask_for_snapshot();
        let indexed = self
            .shared
            .indexed
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .clone();
        // Once the worker is gone its indexer is too: the final snapshot
        // is indexed here (once) rather than answering from an older one.
        let snapshot = match indexed {
            Some(s) if self.is_running() || s.keyframes >= self.shared.latest().keyframes => s,
            _ => self.snapshot(),
        };
        let scores = snapshot.relevance(query)?;
        Ok(Relevance { scores, snapshot })
    }

    /// Renders colour, depth and queries of the map from `camera` (see
    /// [`Mapper::render`]). The worker serves it between frames: while a
    /// keyframe runs, it waits for the rest of that keyframe.
    pub fn render(&self, camera: &Camera) -> Result<RenderedView> {
        self.lend(|m| m.render(camera).map(|(view, _)| view))?
    }

    /// Saves the map into the run folder `dir` (see [`Mapper::save`]),
    /// between frames as [`LiveReader::render`]. Returns the state file.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<PathBuf> {
        let dir = dir.as_ref();
        self.lend(|m| m.save(dir))?
    }

    /// Runs `f` on the calling thread with the mapper, once the worker is
    /// between frames; mapping waits until `f` returns.
    fn lend<R>(&self, f: impl FnOnce(&mut Mapper) -> R) -> Result<R> {
        self.lend_slot(|slot| f(slot.as_mut().expect("a loan holds the mapper")))
    }

    /// Runs `f` on the calling thread with the mapper itself, once the
    /// worker is between frames; `f` gives it back. Mapping waits.
    pub(super) fn lend_owned<R>(&self, f: impl FnOnce(Mapper) -> (Mapper, R)) -> Result<R> {
        self.lend_slot(|slot| {
            let mapper = slot.take().expect("a loan holds the mapper");
            let (mapper, r) = f(mapper);
            *slot = Some(mapper);
            r
        })
    }

    fn lend_slot<R>(&self, f: impl FnOnce(&mut Option<Mapper>) -> R) -> Result<R> {
        let (to, from) = mpsc::channel();
        {
            let mut st = self.shared.lock();
            if st.exited {
                return Err(st.stopped_error());
            }
            st.lends.push_back(to);
        }
        self.shared.work.notify_one();
        let mut lent = from.recv().map_err(|_| self.shared.stopped_error())?;
        Ok(f(&mut lent.mapper))
    }

    /// The last keyframe's image and camera, once one was mapped.
    pub fn last_keyframe(&self) -> Option<Arc<KeyframeImage>> {
        self.shared
            .last_keyframe
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Waits until more than `seen` keyframes are mapped through the
    /// handle, the worker ends, or `max_wait` passes; the keyframes
    /// mapped then; [`LiveReader::snapshot`] then shows them.
    pub fn wait_for_keyframe(&self, seen: u64, max_wait: Duration) -> u64 {
        let deadline = Instant::now() + max_wait;
        let (st, _) = self
            .shared
            .wait_until(deadline, |st| st.keyframes > seen || st.exited);
        st.keyframes
    }

    /// The reports of the keyframes mapped since the last call, oldest
    /// first, when [`LiveOptions::keep_keyframe_reports`](super::LiveOptions::keep_keyframe_reports)
    /// is set (empty otherwise). A reader kept past
    /// [`LiveMapper::finish`](super::LiveMapper::finish) takes the last ones.
    pub fn take_keyframe_reports(&self) -> Vec<crate::mapper::KeyframeReport> {
        self.shared
            .lock()
            .keyframe_reports
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// Whether the worker still runs (it has not ended, whatever stopped
    /// it).
    pub fn is_running(&self) -> bool {
        !self.shared.lock().exited
    }
}
