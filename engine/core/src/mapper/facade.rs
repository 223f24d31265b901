//! The library façade: one value that owns the GPU context and the
//! mapper's parts, with the calls a robot program needs. A frame's route
//! through the parts is in `route.rs`; saving and loading them in
//! `persist/`.

use std::path::{Path, PathBuf};

use super::config::MapperConfig;
use super::dictionary::Dictionary;
use super::export::{DecoderFile, DECODER_FILE};
use super::keyframe_report::MapperStats;
use super::pager::{Pager, PagerSettings};
use super::persist::SavedState;
use super::progress::Progress;
use super::run_folder::{read_one_version, RunFolder, RunStaging, STATE_FILE};
use super::seeder::Seeder;
use super::trainer::Trainer;
use super::workspace::gpu_budget;
use latentam_base::{Error, Result};
use latentam_gpu::{Context, ContextOptions};
use std::sync::atomic::AtomicBool;

use super::eval::Evaluator;
use super::history::History;
use super::relevance_index::RelevanceIndex;
use crate::map::{ExposureTrack, KeyframeSelector};
use latentam_io::CameraPose;

/// A latent Gaussian map built online.
///
/// ```no_run
/// use latentam_io::{AssemblyConfig, McapFrames};
///
/// let mut mapper = latentam_core::mapper::Mapper::new(latentam_core::mapper::MapperConfig::default())?;
/// for frame in McapFrames::open("run.mcap".as_ref(), AssemblyConfig::default())? {
///     mapper.integrate(&frame?)?;
/// }
/// let text_embedding = vec![0.0f32; 512]; // from your vision-language model
/// let query = latentam_core::latent::TextQuery::embedding(text_embedding);
/// let scores = mapper.relevance(&query, latentam_core::mapper::Scored::Gaussians)?; // one per Gaussian
/// mapper.save("out/")?;
/// println!("{} Gaussians", mapper.stats().gaussians);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub struct Mapper {
    pub(super) ctx: Context,
    pub(super) cfg: MapperConfig,
    /// Decides which frames are keyframes.
    pub(super) selector: KeyframeSelector,
    /// The latent head and the embedding model.
    pub(super) dictionary: Dictionary,
    /// New Gaussians from keyframes, and the guesses among them.
    pub(super) seeder: Seeder,
    /// The global map and its GPU window.
    pub(super) pager: Pager,
    /// Stage I and Stage II, sized at the first keyframe.
    pub(super) trainer: Option<Trainer>,
    /// The keyframes kept for replay.
    pub(super) history: History,
    /// Stamp and pose of every keyframe (the history may have let some go).
    pub(super) trajectory: Vec<(i64, CameraPose)>,
    /// Each keyframe's exposure over the map's brightness.
    pub(super) exposure: ExposureTrack,
    /// Counters, the run id, and whether a keyframe failed part-way.
    pub(super) progress: Progress,
    /// Renders views for `render*` and `evaluate` (made on first use).
    pub(super) evaluator: Option<Evaluator>,
    /// Every Gaussian's attention, for relevance queries: built on the
    /// first query, dropped by the next keyframe (only keyframes change the
    /// map and the decoder).
    pub(super) relevance_index: Option<RelevanceIndex>,
}

impl Mapper {
    /// A mapper on the first suitable Vulkan device, with every kernel it
    /// can dispatch built before it returns ([`Mapper::warm_up`]), so the
    /// first keyframe does not wait for kernel compilation (compiled
    /// pipelines are also kept between processes:
    /// `ContextOptions::pipeline_cache_dir`).
    ///
    /// ```no_run
    /// let mut config = latentam_core::mapper::MapperConfig::default();
    /// config.gpu_budget = Some(2 << 30); // bytes of GPU memory the map may use
    /// let mapper = latentam_core::mapper::Mapper::new(config)?;
    /// # Ok::<(), latentam_core::Error>(())
    /// ```
    pub fn new(config: MapperConfig) -> Result<Self> {
        let ctx = Context::new(ContextOptions::default())?;
        let mapper = Self::with_context(&ctx, config)?;
        mapper.warm_up()?;
        Ok(mapper)
    }

    /// A mapper on a context of your choosing (device, validation,
    /// profiling). It sets the context's memory budget. Call
    /// [`Mapper::warm_up`] before the first frame to keep kernel
    /// compilation out of the first keyframe.
    ///
    /// ```no_run
    /// use latentam_gpu::{Context, ContextOptions};
    /// let ctx = Context::new(ContextOptions { profiling: true, ..ContextOptions::default() })?;
    /// let mapper = latentam_core::mapper::Mapper::with_context(&ctx, latentam_core::mapper::MapperConfig::default())?;
    /// mapper.warm_up()?;
    /// # Ok::<(), latentam_core::Error>(())
    /// ```
    pub fn with_context(ctx: &Context, config: MapperConfig) -> Result<Self> {
        config.validate()?;
        ctx.set_memory_budget(Some(gpu_budget(ctx, &config)));
        let pager = PagerSettings {
            radius: config.window_radius,
            sync_distance: config.sync_distance,
            host_budget: config.host_budget,
        };
        let mut pager = Pager::new(config.voxel_size, pager);
        if let Some(dir) = &config.spill_dir {
            pager.set_spill_dir(dir);
        }
        Ok(Mapper {
            ctx: ctx.clone(),
            selector: KeyframeSelector::new(config.keyframes),
            dictionary: Dictionary::new(&config),
            seeder: Seeder::new(config.seeding),
            pager,
            trainer: None,
            history: History::with_cell(config.history_cell),
            trajectory: Vec::new(),
            exposure: ExposureTrack::default(),
            progress: Progress::default(),
            evaluator: None,
            relevance_index: None,
            cfg: config,
        })
    }

    /// The GPU context the mapper runs on (device information, the
    /// profiler's kernel timings).
    pub(crate) fn context(&self) -> &Context {
        &self.ctx
    }

    /// Saves the whole state into the run folder `dir` (created if
    /// missing): [`STATE_FILE`] and, once the map has embeddings,
    /// [`DECODER_FILE`]. The folder is replaced whole and atomically (see
    /// [`RunFolder`]): it must hold nothing but a run's files, and no other
    /// process may be writing it. Returns the state file's path.
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper) -> latentam_core::Result<()> {
    /// let state = mapper.save("runs/kitchen")?;
    /// println!("saved {}", state.display());
    /// # Ok(())
    /// # }
    /// ```
    pub fn save(&mut self, dir: impl AsRef<Path>) -> Result<PathBuf> {
        let folder = RunFolder::lock(dir)?;
        let staging = folder.stage()?;
        self.save_into(&staging)?;
        staging.commit()?;
        Ok(folder.dir().join(STATE_FILE))
    }

    /// Writes [`STATE_FILE`] and [`DECODER_FILE`] (when the map has
    /// embeddings) into a staged run folder, tagged with its run id, for
    /// callers that add files of their own before committing it.
    pub(crate) fn save_into(&mut self, staging: &RunStaging<'_>) -> Result<()> {
        let id = staging.run_id();
        self.save_as(&staging.path().join(STATE_FILE), id)?;
        if let Some(mut decoder) = self.decoder()? {
            decoder.run_id = Some(id.to_string());
            decoder.write(&staging.path().join(DECODER_FILE))?;
        }
        Ok(())
    }

    /// Loads a state saved by [`Mapper::save`] from directory `dir` onto
    /// `ctx`, to continue mapping or to query. A decoder beside it must
    /// come from the same save.
    ///
    /// ```no_run
    /// use latentam_gpu::{Context, ContextOptions};
    /// let ctx = Context::new(ContextOptions::default())?;
    /// let mut mapper = latentam_core::mapper::Mapper::load(&ctx, "runs/kitchen")?;
    /// println!("{} keyframes so far", mapper.stats().keyframes);
    /// # Ok::<(), latentam_core::Error>(())
    /// ```
    pub fn load(ctx: &Context, dir: impl AsRef<Path>) -> Result<Self> {
        Self::load_with(ctx, dir, &|saved| Ok(saved.clone()))
    }

    /// [`Mapper::load`], with the run-time settings (budget, learning
    /// rates, iterations...) that `settings` makes of the saved ones. The
    /// settings that shape the saved state (voxel size, dictionary size,
    /// region count, replay count, history cell, seed, window capacity)
    /// must come back unchanged: a change is refused.
    ///
    /// ```no_run
    /// # fn f(ctx: &latentam_gpu::Context) -> latentam_core::Result<()> {
    /// // Go on with a smaller GPU budget; the map's shape stays as saved.
    /// let mapper = latentam_core::mapper::Mapper::load_with(ctx, "runs/kitchen", &|saved| {
    ///     let mut c = saved.clone();
    ///     c.gpu_budget = Some(512 << 20);
    ///     Ok(c)
    /// })?;
    /// # Ok(())
    /// # }
    /// ```
    pub fn load_with(
        ctx: &Context,
        dir: impl AsRef<Path>,
        settings: &dyn Fn(&MapperConfig) -> Result<MapperConfig>,
    ) -> Result<Self> {
        let dir = dir.as_ref();
        // The state and the decoder of one version, even while a writer
        // swaps the folder.
        let state = read_one_version(dir, || {
            let state = SavedState::read_streaming(&dir.join(STATE_FILE))?;
            let decoder = dir.join(DECODER_FILE);
            if let (Some(id), true) = (state.0.run_id(), decoder.exists()) {
                let theirs = DecoderFile::read(&decoder)?.run_id;
                if theirs.as_deref() != Some(id) {
                    return Err(Error::damaged(
                        dir,
                        format!(
                            "{DECODER_FILE} was written by another run ({}) than {STATE_FILE} \
                             ({id}); the folder mixes two runs",
                            theirs.as_deref().unwrap_or("no run id")
                        ),
                    ));
                }
            }
            Ok(state)
        })?;
        let (state, map) = state;
        let overrides = settings(state.config())?;
        // The settings that shape the saved state stay as saved: a change
        // asked for would be silently ignored, so it is refused.
        let asked = overrides.shape_settings();
        for ((name, saved), (_, asked)) in state.config().shape_settings().into_iter().zip(asked) {
            if saved != asked {
                return Err(Error::config(
                    name,
                    format!(
                        "{name} = {asked} asked for, but the saved map was built with {name} = \
                         {saved}, which a resumed map keeps; map from scratch to change it"
                    ),
                ));
            }
        }
        Self::from_saved(ctx, state, Some(map), Some(overrides))
    }

    /// Counts, memory and timings.
    ///
    /// ```no_run
    /// # fn f(mapper: &latentam_core::mapper::Mapper) -> latentam_core::Result<()> {
    /// let s = mapper.stats();
    /// println!("{} keyframes, {} Gaussians, {} bytes peak GPU", s.keyframes, s.gaussians, s.gpu_peak_bytes);
    /// # Ok(())
    /// # }
    /// ```
    pub fn stats(&self) -> MapperStats {
        let mem = self.ctx.memory_report();
        let mut s = self.progress.stats();
        s.gaussians = self.pager.global().len();
        s.resident = self.pager.resident();
        s.window = self.pager.budget();
        s.gpu_bytes = mem.total.current;
        s.gpu_peak_bytes = mem.total.peak;
        s.gpu_peak_split = super::budget::MemorySplit::of(&mem);
        s.cpu_bytes = self.cpu_bytes();
        s.cpu_peak_bytes = s.cpu_peak_bytes.max(s.cpu_bytes);
        let global = self.pager.global();
        let moved = global.spill_counts();
        s.disk = super::DiskReport {
            spilled_gaussians: global.spilled_len(),
            spilled_blocks: global.spilled_blocks(),
            bytes: global.disk_bytes(),
            blocks_written: moved.written,
            blocks_read: moved.read,
        };
        s.embedding_dim = self.dictionary.head().map(|h| h.config().dim);
        s.embedding_model = self.dictionary.model().map(str::to_string);
        s.kept_keyframes = self.history.len();
        s.run_id = self.progress.run_id().map(str::to_string);
        s
    }

    /// Host bytes of the map, the history and the trajectory.
    pub(super) fn cpu_bytes(&self) -> u64 {
        self.pager.cpu_bytes()
            + self.history.bytes()
            + (self.trajectory.len() * std::mem::size_of::<(i64, CameraPose)>()) as u64
    }

    /// The settings the map is built with.
    ///
    /// ```no_run
    /// # fn f(mapper: &latentam_core::mapper::Mapper) -> latentam_core::Result<()> {
    /// println!("{} atoms, voxel {} m", mapper.config().atoms, mapper.config().voxel_size);
    /// # Ok(())
    /// # }
    /// ```
    pub fn config(&self) -> &MapperConfig {
        &self.cfg
    }

    /// Every keyframe's stamp (ns) and camera-to-world pose, in order.
    pub(crate) fn trajectory(&self) -> &[(i64, CameraPose)] {
        &self.trajectory
    }

    /// The keyframes kept for replay.
    pub(crate) fn history(&self) -> &History {
        &self.history
    }

    /// The embedding model id of the map's region embeddings.
    pub(crate) fn embedding_model(&self) -> Option<&str> {
        self.dictionary.model()
    }

    /// Whether a keyframe failed part-way: the map refuses further frames
    /// and saves (reload the last save to go on).
    pub(crate) fn is_broken(&self) -> bool {
        self.progress.is_broken()
    }

    /// A flag that, once set (say from a signal handler), makes the
    /// keyframe in progress skip its remaining optimisation steps, leaving
    /// the map consistent; clear it to map normally again.
    pub(crate) fn set_hurry_flag(&mut self, flag: &'static AtomicBool) {
        self.progress.set_hurry_flag(flag);
    }

    /// Every Gaussian as it stands, changing nothing (the window's rows
    /// are read, not written back).
    pub(crate) fn gaussians_now(&self) -> Result<latentam_base::HostGaussians> {
        self.pager.gaussians_now(&self.ctx)
    }

    /// Counts frames dropped before reaching the mapper (see
    /// [`KeyframeSelector::count_unseen`]).
    pub(crate) fn count_unseen_frames(&mut self, n: u32) {
        self.selector.count_unseen(n);
    }

    /// The keyframe rule's state: the last keyframe's pose and the frames
    /// offered since.
    pub(crate) fn keyframe_rule_state(&self) -> (Option<CameraPose>, u32) {
        self.selector.state()
    }

    /// The mapper's own hurry flag, which a live handle's `abort` sets.
    pub(crate) fn stop_flag(&self) -> std::sync::Arc<AtomicBool> {
        self.progress.stop_flag()
    }

    /// Writes the rows training changed back to the global map, so that
    /// the global map is current.
    pub(super) fn flush(&mut self) -> Result<()> {
        self.pager.flush(&self.ctx)
    }

    /// Writes the GPU window back to the global map. Unstable: for the
    /// engine's tests that check the window against the global map.
    #[cfg(any(test, feature = "testing"))]
    #[doc(hidden)]
    pub fn write_back_window(&mut self) -> Result<()> {
        self.flush()
    }

    /// The parts behind the façade, read-only. Unstable: for the engine's
    /// tests that check them against each other (the window against the
    /// global map, a loaded state against the saved one).
    #[cfg(any(test, feature = "testing"))]
    #[doc(hidden)]
    pub fn internals(&self) -> Internals<'_> {
        Internals {
            ctx: &self.ctx,
            global: self.pager.global(),
            window: self.pager.window(),
            history: &self.history,
            head: self.dictionary.head(),
        }
    }
}

/// What [`Mapper::internals`] shows. Unstable: for the engine's tests.
#[cfg(any(test, feature = "testing"))]
#[doc(hidden)]
pub struct Internals<'a> {
    /// The GPU context.
    pub ctx: &'a Context,
    /// The global map (current as of the last write-back).
    pub global: &'a crate::map::GlobalMap,
    /// The GPU window, once the first keyframe sized it.
    pub window: Option<&'a crate::map::LocalWindow>,
    /// The keyframes kept for replay.
    pub history: &'a History,
    /// The latent head, once a keyframe with embeddings was mapped.
    pub head: Option<&'a crate::latent::LatentHead>,
}
