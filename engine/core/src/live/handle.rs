//! The live handle: what a robot program holds.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize};
use std::sync::{Arc, Condvar, Mutex, RwLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use latentam_base::{Error, Result};
use latentam_io::Frame;

use super::options::LiveOptions;
use super::queue::{frame_bytes, DropCounts, FrameQueue};
use super::reader::{LiveReader, LiveStatus, Relevance};
use super::shared::{Close, Outcome, Shared, State};
use super::worker;
use crate::latent::TextQuery;
use crate::mapper::MapSnapshot;
use crate::mapper::{Mapper, MapperConfig};
use crate::splat::{Camera, RenderedView};

/// A map built on a worker thread, fed without waiting and read while it
/// grows. It is `Send + Sync`: share it (`Arc`) between the camera
/// callback, the planner and a viewer.
///
/// ```no_run
/// use latentam_core::live::{LiveMapper, LiveOptions};
/// use latentam_core::latent::TextQuery;
/// use latentam_core::mapper::MapperConfig;
///
/// # fn frames() -> Vec<latentam_io::Frame> { vec![] }
/// let live = LiveMapper::new(MapperConfig::default(), LiveOptions::default())?;
/// for frame in frames() {
///     live.submit(frame)?; // returns at once; the worker maps
///     let status = live.status();
///     if status.dropped.total() > 0 {
///         eprintln!("mapper behind: {:?}", status.dropped);
///     }
/// }
/// // Meanwhile, from any thread: "where is the chair?"
/// let chair_embedding = vec![0.0f32; 512]; // from your vision-language model
/// let answer = live.relevance(&TextQuery::embedding(chair_embedding))?;
/// println!("{} Gaussians scored", answer.scores.len());
/// let mapper = live.finish()?; // maps what is queued, returns the map
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct LiveMapper {
    reader: LiveReader,
    worker: Option<JoinHandle<Option<Mapper>>>,
    indexer: Option<JoinHandle<()>>,
}

const _: () = {
    const fn send_sync<T: Send + Sync>() {}
    send_sync::<LiveMapper>();
    send_sync::<MapSnapshot>();
    send_sync::<LiveReader>();
};

impl LiveMapper {
    /// A live mapper on the first suitable Vulkan device, with every
    /// kernel its configuration uses compiled before it returns (see
    /// [`Mapper::new`]); the time that took is [`LiveStatus::ready_ms`].
    pub fn new(config: MapperConfig, options: LiveOptions) -> Result<Self> {
        let start = Instant::now();
        let mapper = Mapper::new(config)?;
        let ready = start.elapsed().as_secs_f64() * 1e3;
        Self::spawn(mapper, options, Some(ready))
    }

    /// A live mapper that goes on with the map saved in the run folder
    /// `dir` (see [`Mapper::load`]), on the first suitable Vulkan device,
    /// every kernel compiled before it returns.
    ///
    /// ```no_run
    /// use latentam_core::live::{LiveMapper, LiveOptions};
    /// let live = LiveMapper::load("runs/kitchen", LiveOptions::default())?;
    /// println!("{} keyframes so far", live.snapshot().keyframes);
    /// # Ok::<(), latentam_core::Error>(())
    /// ```
    pub fn load(dir: impl AsRef<Path>, options: LiveOptions) -> Result<Self> {
        let start = Instant::now();
        let ctx = latentam_gpu::Context::new(latentam_gpu::ContextOptions::default())?;
        let mapper = Mapper::load(&ctx, dir)?;
        mapper.warm_up()?;
        let ready = start.elapsed().as_secs_f64() * 1e3;
        Self::spawn(mapper, options, Some(ready))
    }

    /// A live mapper around a mapper of your making (on a context of your
    /// choosing, or loaded from a save to go on).
    ///
    /// ```no_run
    /// use latentam_core::live::{LiveMapper, LiveOptions};
    /// let ctx = latentam_gpu::Context::new(Default::default())?;
    /// let mapper = latentam_core::mapper::Mapper::load(&ctx, "runs/kitchen")?;
    /// mapper.warm_up()?;
    /// let live = LiveMapper::start(mapper, LiveOptions::default())?;
    /// # Ok::<(), latentam_core::Error>(())
    /// ```
    pub fn start(mapper: Mapper, options: LiveOptions) -> Result<Self> {
        Self::spawn(mapper, options, None)
    }

    fn spawn(mapper: Mapper, options: LiveOptions, ready_ms: Option<f64>) -> Result<Self> {
        let mut queue = FrameQueue::new(
            options.queue_frames,
            options.queue_bytes,
            options.keep_candidates,
            mapper.config().keyframes,
        );
        let (last, since) = mapper.keyframe_rule_state();
        queue.start_after(last, since);
        let first = MapSnapshot::of(&mapper, options.index)?;
        let stats = mapper.stats();
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                queue,
                lends: VecDeque::new(),
                close: None,
                busy: false,
                exited: false,
                submitted: 0,
                integrated: 0,
                keyframes: 0,
                dropped: DropCounts::default(),
                last_latency_ms: None,
                last_stamp_latency_ms: None,
                last_keyframe_ms: None,
                recent: VecDeque::new(),
                last_error: None,
                stopped: None,
                fatal: false,
                wants_index: false,
                snapshot_wanted: false,
                published: 0,
                snapshots: 0,
                gaussians: stats.gaussians,
                gpu_bytes: stats.gpu_bytes,
                outcomes: None,
                keyframe_reports: options.keep_keyframe_reports.then(Vec::new),
            }),
            work: Condvar::new(),
            room: Condvar::new(),
            index_wake: Condvar::new(),
            snapshot: RwLock::new(Arc::new(first)),
            last_keyframe: RwLock::new(None),
            indexed: RwLock::new(None),
            stop: mapper.stop_flag(),
            closing: AtomicBool::new(false),
            readers: AtomicUsize::new(0),
            options,
            ready_ms,
        });
        let spawn_err = |e: std::io::Error| Error::Io {
            path: PathBuf::from("(thread)"),
            source: e,
        };
        let s = shared.clone();
        let worker = std::thread::Builder::new()
            .name("latentam-mapper".into())
            .spawn(move || worker::run(mapper, s))
            .map_err(spawn_err)?;
        let s = shared.clone();
        let indexer = std::thread::Builder::new()
            .name("latentam-index".into())
            .spawn(move || worker::index_snapshots(s))
            .map_err(spawn_err)?;
        Ok(LiveMapper {
            reader: LiveReader::first(shared),
            worker: Some(worker),
            indexer: Some(indexer),
        })
    }

    /// Queues a frame for the worker and returns at once: it never waits
    /// for GPU work. When the queue is full, frames are dropped by the
    /// policy of [`DropCounts`] (those that cannot become keyframes
    /// first, then the oldest candidates) and counted in
    /// [`LiveStatus::dropped`]. Errors for a frame that does not hold
    /// together ([`Error::BadFrame`], see `Frame::check`: image sizes,
    /// a rigid pose, a pinhole camera, embeddings that fit their layout)
    /// and once the worker has stopped ([`Error::Stopped`], with the
    /// cause).
    pub fn submit(&self, frame: Frame) -> Result<()> {
        frame.check()?;
        let mut st = self.shared().lock();
        if let Some(e) = &st.stopped {
            return Err(Error::Stopped(e.clone()));
        }
        st.submitted += 1;
        let State { queue, dropped, .. } = &mut *st;
        queue.admit(frame, dropped);
        drop(st);
        self.shared().work.notify_one();
        Ok(())
    }

    /// Queues a frame, waiting up to `max_wait` for room instead of
    /// dropping anything: what mapping a recorded log wants. Gives the
    /// frame back if there was still no room.
    pub fn submit_waiting(&self, frame: Frame, max_wait: Duration) -> Result<Option<Frame>> {
        frame.check()?;
        self.submit_checked_waiting(frame, max_wait)
    }

    /// [`LiveMapper::submit_waiting`] for a frame that passed
    /// `Frame::check` already: one given back to wait again (checking
    /// reads every label of its mask).
    pub(crate) fn submit_checked_waiting(
        &self,
        frame: Frame,
        max_wait: Duration,
    ) -> Result<Option<Frame>> {
        let bytes = frame_bytes(&frame);
        let deadline = Instant::now() + max_wait;
        let (mut st, room) = self.shared().wait_until(deadline, |st| {
            st.stopped.is_some() || st.queue.takes_without_dropping(bytes)
        });
        if st.stopped.is_some() {
            return Err(st.stopped_error());
        }
        if !room {
            return Ok(Some(frame));
        }
        st.submitted += 1;
        let State { queue, dropped, .. } = &mut *st;
        queue.admit(frame, dropped);
        drop(st);
        self.shared().work.notify_one();
        Ok(None)
    }

    /// Where mapping stands: the queue, drops, latencies, errors.
    pub fn status(&self) -> LiveStatus {
        self.reader.status()
    }

    /// The map as of the last keyframe (see [`LiveReader::snapshot`]:
    /// taken when read, it waits at most for the frame in progress).
    pub fn snapshot(&self) -> Arc<MapSnapshot> {
        self.reader.snapshot()
    }

    /// The newest snapshot taken, without waiting (see
    /// [`LiveReader::latest_snapshot`]).
    pub fn latest_snapshot(&self) -> Arc<MapSnapshot> {
        self.reader.latest_snapshot()
    }

    /// Relevance of every Gaussian to `query` (see [`LiveReader::relevance`]).
    pub fn relevance(&self, query: &TextQuery) -> Result<Relevance> {
        self.reader.relevance(query)
    }

    /// Renders colour, depth and queries of the map from `camera` (see
    /// [`LiveReader::render`]).
    pub fn render(&self, camera: &Camera) -> Result<RenderedView> {
        self.reader.render(camera)
    }

    /// Saves the map into the run folder `dir` (see [`LiveReader::save`]).
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<PathBuf> {
        self.reader.save(dir)
    }

    /// A reader of this map for another thread or a viewer: status,
    /// snapshots, queries, renders and saves, without the right to
    /// submit or close. It stays usable after the handle closes (its
    /// loans then answer [`Error::Stopped`]).
    pub fn reader(&self) -> LiveReader {
        self.reader.clone()
    }

    /// Runs `f` with the mapper itself between frames (see
    /// [`LiveReader::lend_owned`]).
    pub(crate) fn lend_owned<R>(&self, f: impl FnOnce(Mapper) -> (Mapper, R)) -> Result<R> {
        self.reader.lend_owned(f)
    }

    fn shared(&self) -> &Shared {
        &self.reader.shared
    }

    /// Keeps what became of each frame from now on, for
    /// [`LiveMapper::take_outcomes`].
    pub(crate) fn record_outcomes(&self) {
        self.shared().lock().outcomes.get_or_insert_with(Vec::new);
    }

    /// What became of each frame since the last call.
    pub(crate) fn take_outcomes(&self) -> Vec<Outcome> {
        self.shared()
            .lock()
            .outcomes
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// Waits until every queued frame is mapped (or the worker stopped),
    /// up to `max_wait`; whether it is.
    pub fn wait_idle(&self, max_wait: Duration) -> bool {
        let deadline = Instant::now() + max_wait;
        self.shared()
            .wait_until(deadline, |st| {
                (st.queue.len() == 0 && !st.busy) || st.stopped.is_some() || st.exited
            })
            .1
    }

    /// Maps every queued frame, stops the worker and returns the mapper.
    /// Errors when the worker stopped on a failure that left no usable
    /// map (a keyframe that failed part-way, a lost device, a panic).
    pub fn finish(mut self) -> Result<Mapper> {
        let (mapper, stopped, fatal) = self.close(Close::Finish);
        match (mapper, stopped) {
            (Some(m), None) => Ok(m),
            (Some(m), Some(_)) if !fatal => Ok(m),
            (_, Some(e)) => Err(Error::Stopped(e)),
            (None, None) => Err(self.shared().stopped_error()),
        }
    }

    /// Stops as soon as it can: the keyframe in progress skips its
    /// remaining optimisation steps (within about one Stage I step), the
    /// queued frames are dropped (counted as `aborted`), and the mapper
    /// is returned with what it mapped.
    pub fn abort(mut self) -> Result<Mapper> {
        let (mapper, stopped, _) = self.close(Close::Abort);
        mapper.ok_or_else(|| match stopped {
            Some(e) => Error::Stopped(e),
            None => self.shared().stopped_error(),
        })
    }

    /// [`LiveMapper::finish`] (or [`LiveMapper::abort`]) for [`LogRun`](super::LogRun),
    /// which keeps a broken map to report on it: the mapper (if any), what
    /// stopped the worker, and the outcomes not taken yet.
    pub(crate) fn close_keeping_failures(
        mut self,
        abort: bool,
    ) -> (Option<Mapper>, Option<Arc<Error>>, Vec<Outcome>) {
        let how = if abort { Close::Abort } else { Close::Finish };
        let (mapper, stopped, _) = self.close(how);
        (mapper, stopped, self.take_outcomes())
    }

    fn close(&mut self, how: Close) -> (Option<Mapper>, Option<Arc<Error>>, bool) {
        self.shared().ask_to_close(how);
        let mapper = self.worker.take().and_then(|w| w.join().ok().flatten());
        if let Some(i) = self.indexer.take() {
            let _ = i.join();
        }
        let st = self.shared().lock();
        (mapper, st.stopped.clone(), st.fatal)
    }
}

impl Drop for LiveMapper {
    /// Aborts and waits for the worker up to
    /// [`LiveOptions::drop_timeout`]; a worker stuck longer (a GPU that
    /// stopped answering) is left to end on its own.
    fn drop(&mut self) {
        if self.worker.is_none() {
            return;
        }
        self.shared().ask_to_close(Close::Abort);
        let deadline = Instant::now() + self.shared().options.drop_timeout;
        if !self.shared().wait_until(deadline, |st| st.exited).1 {
            log::warn!("the mapping worker did not end in time; leaving it to end on its own");
            return;
        }
        if let Some(w) = self.worker.take() {
            let _ = w.join();
        }
        if let Some(i) = self.indexer.take() {
            let _ = i.join();
        }
    }
}
