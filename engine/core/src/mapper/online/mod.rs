//! The per-keyframe loop (paper Alg. 1) over the pieces in `map`,
//! `latent` and the [`Trainer`].

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;

use super::budget::{
    head_bytes, largest_row_bytes, pixel_bytes, window_budget, MemorySplit, WindowBudget,
};
use super::config::MapperConfig;
use super::history::{History, KeyframeRecord};
use super::trainer::{views_per_chunk, Trainer, TrainerConfig, DEFAULT_CHUNK_PIXELS};
use crate::latent::{projected_queries, LatentHead, LatentHeadConfig};
use crate::map::{
    relative_exposure, seed_from_frame, Companion, ExposureTrack, GlobalMap, KeySet,
    KeyframeSelector, LocalWindow, PendingSync, QueryInit, RegionQueries, SyncPlan, ViewCoverage,
    VoxelKey,
};
use crate::splat::{Channels, QUERY_DIM};
use latentam_base::{Error, Result};
use latentam_gpu::{Context, GpuCalls, GpuSpan, Submission};
use latentam_io::{embedding_space, CameraPose, Frame};

mod growth;
mod paging;
mod stages;

use super::keyframe_report::{
    Integrated, KeyframeGpuCalls, KeyframeGpuWork, KeyframeReport, KeyframeTimings, MapperStats,
    PagingReport,
};

/// The online mapper's state.
///
/// ```no_run
/// # fn f(frames: &[latentam_io::Frame]) -> latentam_core::Result<()> {
/// use latentam_gpu::{Context, ContextOptions};
/// use latentam_core::mapper::{Integrated, MapperConfig, OnlineMapper};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let mut mapper = OnlineMapper::new(&ctx, MapperConfig::default())?;
/// for frame in frames {
///     if let Integrated::Keyframe(report) = mapper.integrate(frame)? {
///         println!("{report:?}");
///     }
/// }
/// mapper.flush()?; // write the window back before reading the global map
/// println!("{} Gaussians", mapper.global().len());
/// # Ok(())
/// # }
/// ```
pub struct OnlineMapper {
    pub(super) ctx: Context,
    pub(super) cfg: MapperConfig,
    pub(super) global: GlobalMap,
    pub(super) window: Option<LocalWindow>,
    pub(super) window_budget: Option<WindowBudget>,
    pub(super) selector: KeyframeSelector,
    pub(super) history: History,
    pub(super) head: Option<LatentHead>,
    pub(super) trainer: Option<Trainer>,
    pub(super) last_sync: Option<DVec3>,
    /// The last sync left Gaussians within the radius out of the window.
    pub(super) window_partial: bool,
    /// Stage I changed resident Gaussians since the last write-back.
    pub(super) window_dirty: bool,
    pub(super) frames: u64,
    /// Stamp of the last frame integrated: where a resumed run goes on.
    pub(super) last_stamp_ns: Option<i64>,
    pub(super) stats: MapperStats,
    /// The embedding model of the map's region embeddings (first seen).
    pub(super) model: Option<String>,
    /// Stamp and pose of every keyframe (the history may have let some go).
    pub(super) trajectory: Vec<(i64, CameraPose)>,
    /// Each keyframe's exposure over the map's brightness.
    pub(super) exposure: ExposureTrack,
    /// Gaussians seeded where their keyframe measured no depth (holes
    /// filled from their neighbours), until a later keyframe measures
    /// their surface.
    pub(super) guesses: KeySet,
    /// Guesses a later keyframe saw in front of the surface it measured:
    /// removed at the next pruning.
    pub(super) superseded: KeySet,
    /// The run folder version the state was loaded from.
    pub(super) run_id: Option<String>,
    /// A keyframe step failed after it had changed the map: the state is
    /// neither the one before that frame nor the one after it, so it is
    /// neither saved nor mapped further.
    pub(super) broken: Option<String>,
    /// Set by the caller to have the keyframe in progress skip its
    /// remaining optimisation steps (see [`OnlineMapper::set_hurry_flag`]).
    pub(super) hurry: Option<&'static AtomicBool>,
    /// The same, set by a live handle's `abort` (see
    /// [`OnlineMapper::stop_flag`]).
    pub(super) stop: Arc<AtomicBool>,
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

impl OnlineMapper {
    /// An empty map on `ctx`. Sets the context's memory budget to
    /// [`MapperConfig::gpu_budget`] (or its default); the window is sized
    /// at the first keyframe, when the image size is known.
    pub fn new(ctx: &Context, cfg: MapperConfig) -> Result<Self> {
        cfg.validate()?;
        ctx.set_memory_budget(Some(Self::budget_of(ctx, &cfg)));
        Ok(OnlineMapper {
            ctx: ctx.clone(),
            global: GlobalMap::new(cfg.voxel_size),
            window: None,
            window_budget: None,
            selector: KeyframeSelector::new(cfg.keyframes),
            history: History::with_cell(cfg.history_cell),
            trajectory: Vec::new(),
            exposure: ExposureTrack::default(),
            guesses: KeySet::default(),
            superseded: KeySet::default(),
            head: None,
            trainer: None,
            last_sync: None,
            window_partial: false,
            window_dirty: false,
            frames: 0,
            last_stamp_ns: None,
            stats: MapperStats::default(),
            model: None,
            run_id: None,
            broken: None,
            hurry: None,
            stop: Arc::default(),
            cfg,
        })
    }

    /// Makes a stop request prompt: once `flag` is set (from a signal
    /// handler, say: an atomic store is all it takes), the keyframe in
    /// progress skips its remaining Stage I iterations and its Stage II
    /// and completes as soon as it can, leaving a consistent map with that
    /// keyframe less trained. The flag is only read.
    ///
    /// ```no_run
    /// use std::sync::atomic::{AtomicBool, Ordering};
    /// static STOP: AtomicBool = AtomicBool::new(false);
    /// let mut mapper = latentam_core::mapper::Mapper::new(latentam_core::mapper::MapperConfig::default())?;
    /// mapper.set_hurry_flag(&STOP); // through the façade
    /// // elsewhere: STOP.store(true, Ordering::SeqCst);
    /// # Ok::<(), latentam_core::Error>(())
    /// ```
    pub fn set_hurry_flag(&mut self, flag: &'static AtomicBool) {
        self.hurry = Some(flag);
    }

    /// A second hurry flag, owned by the mapper, for a handle that lives
    /// no longer than the program (the live handle's `abort`): set, it
    /// has the same effect as the flag of [`OnlineMapper::set_hurry_flag`].
    pub(crate) fn stop_flag(&self) -> Arc<AtomicBool> {
        self.stop.clone()
    }

    /// Whether either hurry flag is set.
    pub(super) fn hurried(&self) -> bool {
        self.hurry.is_some_and(|f| f.load(Ordering::SeqCst)) || self.stop.load(Ordering::SeqCst)
    }

    /// The id of the run folder version this state was loaded from (see
    /// [`super::RunFolder`]), when it was.
    pub fn run_id(&self) -> Option<&str> {
        self.run_id.as_deref()
    }

    /// Whether a keyframe step failed part-way (after changing the map):
    /// such a state cannot be saved or mapped further; the last save is
    /// the consistent state to go on from.
    pub fn is_broken(&self) -> bool {
        self.broken.is_some()
    }

    pub(super) fn check_consistent(&self) -> Result<()> {
        match &self.broken {
            None => Ok(()),
            Some(why) => Err(Error::InvalidArgument(format!(
                "the map is in the middle of a keyframe that failed ({why}); it cannot be saved \
                 or mapped further: load the last save instead"
            ))),
        }
    }

    /// Refuses a query vocabulary the map cannot score: one of another
    /// embedding dimension or from another model than the map's region
    /// embeddings (their spaces differ, so scores would mean nothing).
    /// An `oracle:` prefix on either side does not count as a difference.
    pub fn check_vocabulary(&self, v: &latentam_io::Vocabulary) -> Result<()> {
        let Some(head) = &self.head else {
            return Err(Error::NoEmbeddings);
        };
        let dim = head.config().dim;
        if v.dim != dim {
            return Err(Error::EmbeddingDimension {
                map: dim,
                given: v.dim,
                context: Some(format!("the vocabulary's, of `{}`", v.model)),
            });
        }
        if let Some(m) = &self.model {
            if embedding_space(m) != embedding_space(&v.model) {
                return Err(Error::EmbeddingModel {
                    map: m.clone(),
                    given: v.model.clone(),
                    context: Some("the vocabulary's".into()),
                });
            }
        }
        Ok(())
    }

    /// Refuses a frame whose embeddings do not suit the map (model or
    /// dimension), before anything changes.
    fn check_frame(&self, frame: &Frame) -> Result<()> {
        if let Some(e) = &frame.embeddings {
            // The caller knows which frame it offered.
            let context = || None;
            if let Some(m) = &self.model {
                if embedding_space(m) != embedding_space(&e.model) {
                    return Err(Error::EmbeddingModel {
                        map: m.clone(),
                        given: e.model.clone(),
                        context: context(),
                    });
                }
            }
            if let Some(head) = &self.head {
                if head.config().dim != e.dim {
                    return Err(Error::EmbeddingDimension {
                        map: head.config().dim,
                        given: e.dim,
                        context: context(),
                    });
                }
            }
        }
        Ok(())
    }

    fn budget_of(ctx: &Context, cfg: &MapperConfig) -> u64 {
        cfg.gpu_budget
            .unwrap_or(ctx.info().device_local_bytes / 2)
            .max(1)
    }

    /// The configuration.
    pub fn config(&self) -> &MapperConfig {
        &self.cfg
    }

    /// The GPU context.
    pub fn context(&self) -> &Context {
        &self.ctx
    }

    /// The global map (current up to the last window sync; see
    /// [`OnlineMapper::flush`]).
    pub fn global(&self) -> &GlobalMap {
        &self.global
    }

    /// The GPU window, once the first keyframe sized it (for the tests
    /// that check it against the global map).
    #[cfg(any(test, feature = "testing"))]
    pub fn window(&self) -> Option<&LocalWindow> {
        self.window.as_ref()
    }

    /// The latent head, once a frame with embeddings has been seen.
    pub fn head(&self) -> Option<&LatentHead> {
        self.head.as_ref()
    }

    /// The keyframes so far.
    pub fn history(&self) -> &History {
        &self.history
    }

    /// Stamp and camera-to-world pose of every keyframe mapped, in order.
    pub fn trajectory(&self) -> &[(i64, CameraPose)] {
        &self.trajectory
    }

    /// Every keyframe's exposure over the map's brightness.
    pub fn exposure(&self) -> &ExposureTrack {
        &self.exposure
    }

    /// Whether `frame` is at or before the last frame integrated.
    pub(crate) fn already_mapped(&self, frame: &Frame) -> bool {
        self.last_stamp_ns
            .is_some_and(|last| frame.stamp_ns <= last)
    }

    /// Counts, memory and summed timings.
    pub fn stats(&self) -> MapperStats {
        let mem = self.ctx.memory_report();
        let mut s = self.stats.clone();
        s.frames = self.frames;
        s.last_frame_stamp_ns = self.last_stamp_ns;
        s.gaussians = self.global.len();
        s.resident = self.window.as_ref().map_or(0, |w| w.len());
        s.window = self.window_budget;
        s.gpu_bytes = mem.total.current;
        s.gpu_peak_bytes = mem.total.peak;
        s.gpu_peak_split = MemorySplit::of(&mem);
        s.cpu_bytes = self.cpu_bytes();
        s.cpu_peak_bytes = s.cpu_peak_bytes.max(s.cpu_bytes);
        s
    }

    fn cpu_bytes(&self) -> u64 {
        self.global.bytes()
            + self.history.bytes()
            + (self.trajectory.len() * std::mem::size_of::<(i64, CameraPose)>()) as u64
            + self.window.as_ref().map_or(0, |w| {
                w.len() as u64 * std::mem::size_of::<VoxelKey>() as u64
            })
    }

    /// The model id of the region embeddings mapped so far (`None` before
    /// the first keyframe with embeddings).
    pub fn embedding_model(&self) -> Option<&str> {
        self.model.as_deref()
    }

    /// Integrates one frame: keyframe selection, then for a keyframe the
    /// dictionary update, Gaussian seeding (new Gaussians go straight into
    /// the window), Stage I over the keyframe and B past ones, Stage II
    /// with the window's re-synchronisation running beside it on the
    /// transfer queue, the history append and, at its interval, pruning.
    ///
    /// A frame is counted once its step has completed. A frame refused
    /// for its content (see the errors) leaves the map exactly as it was;
    /// a failure part-way through a keyframe (a lost device, GPU memory)
    /// leaves it unusable ([`OnlineMapper::is_broken`]).
    pub fn integrate(&mut self, frame: &Frame) -> Result<Integrated> {
        frame.check()?;
        self.integrate_checked(frame)
    }

    /// [`OnlineMapper::integrate`] for a frame that passed `Frame::check`
    /// already (the live handle checks at `submit`, on the caller's
    /// thread).
    pub(crate) fn integrate_checked(&mut self, frame: &Frame) -> Result<Integrated> {
        self.check_consistent()?;
        self.check_frame(frame)?;
        let selector = self.selector.state();
        if !self.selector.decide(frame, &self.global).keyframe {
            self.frames += 1;
            self.last_stamp_ns = Some(frame.stamp_ns);
            return Ok(Integrated::Skipped);
        }
        // The first keyframe sizes the window against the budget before any
        // GPU work, so a configuration that cannot map fails here, with the
        // setting to change, and with the map as it was.
        let dim = self
            .head
            .as_ref()
            .map(|h| h.config().dim)
            .or(frame.embeddings.as_ref().map(|e| e.dim));
        let pixels = frame.color.width as u64 * frame.color.height as u64;
        if let Err(e) = self.ensure_workspace(pixels, dim) {
            self.selector.restore(selector.0, selector.1);
            return Err(e);
        }
        self.broken = Some(format!("keyframe at {} ns", frame.stamp_ns));
        let report = self.integrate_keyframe(frame)?;
        self.broken = None;
        self.frames += 1;
        self.last_stamp_ns = Some(frame.stamp_ns);
        Ok(Integrated::Keyframe(report))
    }

    fn integrate_keyframe(&mut self, frame: &Frame) -> Result<Box<KeyframeReport>> {
        let frame_index = self.frames;
        let t_start = Instant::now();
        let mut calls = KeyframeGpuCalls::default();
        let ctx = self.ctx.clone();
        let work_before = ctx.gpu_work();
        let mut since = ctx.gpu_calls();
        let mut lap = |stage: &mut GpuCalls| {
            let now = ctx.gpu_calls();
            *stage = *stage + (now - since);
            since = now;
        };
        let mut timings = KeyframeTimings::default();
        let mut paging = Vec::new();
        let mut record = KeyframeRecord::from_frame(frame);
        let keyframe = self.stats.keyframes;
        let seed = self.cfg.seed ^ keyframe.wrapping_mul(0x9e37_79b9);

        if let Some(e) = &frame.embeddings {
            // The first model seen is the map's (`check_frame` refused any
            // other before anything changed).
            self.model.get_or_insert_with(|| e.model.clone());
        }
        // Each CPU stage is a host span of the profile (`trace.json`),
        // beside the GPU's commands and the waits for them.
        let keyframe_span = ctx.host_span("keyframe");
        ((), timings.kmeans_ms) = in_span(&ctx, "dictionary", || self.update_dictionary(&record))?;
        lap(&mut calls.dictionary);

        // What the map already explains at this pose, then new Gaussians,
        // which must be resident for Stage I.
        let centre = frame.pose.translation;
        let new_keys;
        (new_keys, timings.insertion_ms) = in_span(&ctx, "seeding", || {
            self.insert_new_gaussians(frame, &mut record, seed, &mut timings, &mut paging)
        })?;
        lap(&mut calls.insertion);

        // Stage I on the keyframe and B past ones.
        let stage_one;
        (stage_one, timings.stage_one_ms) = in_span(&ctx, "stage I", || {
            self.train_stage_one(&record, seed, centre)
        })?;
        lap(&mut calls.stage_one);

        // Stage II reads no Gaussian: the window pages beside it. The
        // paging batch is submitted first so that it waits for Stage I
        // only (see `Recorder::submit`).
        let stage_two;
        (stage_two, timings.stage_two_ms) = in_span(&ctx, "stage II and paging", || {
            self.stage_two_and_paging(centre, &mut timings, &mut paging, &mut lap, &mut calls)
        })?;

        let (stamp_ns, exposure) = (record.stamp_ns, record.exposure);
        self.trajectory.push((stamp_ns, frame.pose));
        self.exposure.push(stamp_ns, exposure);
        self.history.push(record);
        self.stats.keyframes += 1;
        let interval = self.cfg.prune_interval as u64;
        let pruned;
        (pruned, timings.prune_ms) = in_span(&ctx, "pruning", || {
            if interval > 0 && self.stats.keyframes.is_multiple_of(interval) {
                self.prune()
            } else {
                Ok(0)
            }
        })?;
        timings.total_ms = ms_since(t_start);
        drop(keyframe_span);
        lap(&mut calls.prune);

        for p in &paging {
            self.stats.evicted += p.evicted as u64;
            self.stats.fetched += p.fetched as u64;
            self.stats.over_capacity += p.over_capacity as u64;
        }
        self.stats.timings.add(&timings);
        let work = ctx.gpu_work() - work_before;
        self.stats.gpu_work += &work;
        let cpu_bytes = self.cpu_bytes();
        self.stats.cpu_peak_bytes = self.stats.cpu_peak_bytes.max(cpu_bytes);
        Ok(Box::new(KeyframeReport {
            index: keyframe,
            frame: frame_index,
            stamp_ns,
            added: new_keys.len(),
            stage_one,
            stage_two,
            pruned,
            paging,
            timings,
            gaussians: self.global.len(),
            resident: self.window.as_ref().map_or(0, |w| w.len()),
            gpu_bytes: self.ctx.memory_report().total.current,
            cpu_bytes,
            atoms: self.head.as_ref().map_or(0, |h| h.atom_count()),
            exposure,
            gpu_calls: calls,
            gpu_work: KeyframeGpuWork::of(&work),
        }))
    }
}

/// Runs one CPU stage of a keyframe as the host span `name` of the
/// profile: its result and its wall time in milliseconds.
fn in_span<T>(
    ctx: &Context,
    name: &'static str,
    stage: impl FnOnce() -> Result<T>,
) -> Result<(T, f64)> {
    let t = Instant::now();
    let _span = ctx.host_span(name);
    let out = stage()?;
    Ok((out, ms_since(t)))
}
