//! Between a mapper and its saved state: downloading the GPU state into an
//! archive, and creating the GPU buffers of a loaded one.

use super::write::{ChunkVisitor, MapRows, StateRef};
use super::*;
use crate::map::GlobalMap;
use crate::mapper::facade::Mapper;
use crate::mapper::progress::Progress;
use crate::mapper::seeder::Seeder;

/// Reads a whole device buffer as bytes (first `bytes` kept).
fn download_bytes(ctx: &Context, buf: &Buffer, bytes: u64) -> Result<Vec<u8>> {
    let mut v: Vec<u8> = ctx.download(buf)?;
    v.truncate(bytes as usize);
    Ok(v)
}

impl Mapper {
    /// Saves the whole state to the file `path` (replaced atomically)
    /// under a fresh run id. Unstable: for the engine's tests.
    #[cfg(any(test, feature = "testing"))]
    #[doc(hidden)]
    pub fn save_file(&mut self, path: &Path) -> Result<()> {
        self.save_as(path, &crate::mapper::new_run_id())
    }

    /// Saves the whole state to the file `path` (replaced atomically),
    /// recording `run_id`: the id of the run folder version the file
    /// belongs to (see [`RunStaging::run_id`](crate::mapper::RunStaging::run_id)).
    /// The window is written back to the global map first.
    pub(in crate::mapper) fn save_as(&mut self, path: &Path, run_id: &str) -> Result<()> {
        self.progress.check_consistent()?;
        self.flush()?;
        let ctx = self.ctx.clone();
        let window = self.download_window(&ctx)?;
        let head = self.download_head(&ctx)?;
        check_finite(path, head.as_ref(), window.as_ref())?;
        let map = LiveRows {
            global: self.pager.global(),
            seeder: &self.seeder,
            path,
        };
        let archive = StateRef {
            run_id: Some(run_id),
            config: &self.cfg,
            counters: self.progress.counters(),
            model: self.dictionary.model(),
            selector: self.selector.state(),
            last_sync: self.pager.last_sync(),
            map: &map,
            head: head.as_ref(),
            history: (0..self.history.len())
                .filter_map(|i| self.history.get(i))
                .collect(),
            trajectory: &self.trajectory,
            // In the trajectory's order (the track is in time order).
            exposure: self
                .trajectory
                .iter()
                .map(|(stamp_ns, _)| self.exposure.at(*stamp_ns))
                .collect(),
            window: window.as_ref(),
        }
        .into_archive()?;
        archive.write_file(path)
    }

    /// The window's residents and their optimiser rows, from the GPU.
    fn download_window(&self, ctx: &Context) -> Result<Option<SavedWindow>> {
        Ok(
            match (self.pager.window(), &self.trainer, self.pager.budget()) {
                (Some(window), Some(trainer), Some(sized)) => {
                    let n = window.len() as u64;
                    let state = trainer
                        .optimizer()
                        .state()
                        .into_iter()
                        .map(|(buf, row)| download_bytes(ctx, buf, n * row))
                        .collect::<Result<Vec<_>>>()?;
                    Some(SavedWindow {
                        capacity: sized.capacity,
                        view_pixels: self.history.get(0).map_or(0, |k| k.camera.pixels()),
                        keys: window.keys().to_vec(),
                        state,
                    })
                }
                _ => None,
            },
        )
    }

    /// The latent head's parameters and optimiser state, from the GPU.
    fn download_head(&self, ctx: &Context) -> Result<Option<SavedHead>> {
        Ok(match self.dictionary.head() {
            Some(head) => {
                let d = head.config().dim as usize;
                let k = head.config().atoms as usize;
                let used = head.atom_count();
                let mut atoms: Vec<f32> = ctx.download(head.atoms())?;
                atoms.truncate(k * d);
                let mut anchors: Vec<f32> = ctx.download(head.anchor())?;
                anchors.truncate(k * d);
                let mut weights: Vec<f32> = ctx.download(head.kmeans().weights())?;
                weights.truncate(used as usize);
                let adam = head
                    .optimizer_state()
                    .into_iter()
                    .map(|(buf, _)| ctx.download::<u8>(buf))
                    .collect::<Result<Vec<_>>>()?;
                Some(SavedHead {
                    dim: d as u32,
                    used,
                    w: ctx.download(head.w())?,
                    atoms,
                    anchors,
                    weights,
                    adam,
                })
            }
            None => None,
        })
    }

    /// Loads a state saved by [`Mapper::save_file`] onto `ctx`.
    /// Unstable: for the engine's tests.
    #[cfg(any(test, feature = "testing"))]
    #[doc(hidden)]
    pub fn load_file(ctx: &Context, path: &Path, overrides: Option<MapperConfig>) -> Result<Self> {
        let (state, map) = SavedState::read_streaming(path)?;
        Self::from_saved(ctx, state, Some(map), overrides)
    }

    /// A mapper on `ctx` with the state `saved`: creates the GPU buffers
    /// and uploads the window, the latent head and their optimiser state.
    /// `overrides` replaces the saved configuration's run-time settings
    /// (budget, learning rates...) when given; the settings that shape the
    /// saved state (voxel size, dictionary size, replay count, window
    /// capacity) are kept.
    ///
    /// The global map is `saved`'s, or read from `streamed` when given
    /// (`saved` was then read without it): inserted a chunk at a time and
    /// spilled to the host budget as it comes, so loading holds no more of
    /// the map than mapping would.
    pub(in crate::mapper) fn from_saved(
        ctx: &Context,
        saved: SavedState,
        streamed: Option<StreamedMap>,
        overrides: Option<MapperConfig>,
    ) -> Result<Self> {
        let corrupt = |why: String| Error::damaged(&saved.origin, why);
        let mut cfg = overrides.unwrap_or_else(|| saved.config.clone());
        cfg.keep_shape_of(&saved.config);
        if let Some(w) = &saved.window {
            cfg.window_capacity = Some(w.capacity);
        }
        let mut m = Mapper::with_context(ctx, cfg)?;
        m.progress = Progress::restored(saved.counters, saved.run_id);
        m.dictionary.restore_model(saved.model);
        m.selector.restore(saved.selector.0, saved.selector.1);
        m.pager.restore_last_sync(saved.last_sync);
        let restore = |m: &mut Mapper, key: VoxelKey, g: Gaussian, flag: u8| -> Result<()> {
            // A block spilled while the file was read comes back, and the
            // insertion is tried again (a file of an older version need not
            // list a block's Gaussians together).
            let global = m.pager.global_mut();
            let inserted = global.insert_at(key, g)
                || (global.load(GlobalMap::block_of(key))? && global.insert_at(key, g));
            if !inserted {
                return Err(corrupt(format!("voxel {key:?} appears twice in the map")));
            }
            match flag {
                GUESSED => m.seeder.restore_guess(key),
                SUPERSEDED => m.seeder.restore_superseded(key),
                _ => {}
            }
            Ok(())
        };
        for ((key, g), flag) in saved.map.into_iter().zip(saved.guesses) {
            restore(&mut m, key, g, flag)?;
        }
        if let Some(streamed) = &streamed {
            // 64 Ki Gaussians (12 MiB) at a time.
            streamed.for_each_chunk(1 << 16, |(keys, gaussians, flags)| {
                for ((&key, &g), &flag) in keys.iter().zip(&gaussians).zip(&flags) {
                    restore(&mut m, key, g, flag)?;
                }
                m.pager.spill_to_budget().map(|_| ())
            })?;
        }

        // Latent head.
        if let Some(h) = saved.head {
            let head = m.dictionary.make_head(ctx, h.dim)?;
            ctx.upload(head.w(), 0, &h.w)?;
            ctx.upload(head.atoms(), 0, &h.atoms)?;
            ctx.upload(head.anchor(), 0, &h.anchors)?;
            head.kmeans().restore(ctx, h.used, &h.weights)?;
            let expected: Vec<u64> = head
                .optimizer_state()
                .iter()
                .map(|(b, _)| b.bytes())
                .collect();
            upload_state(
                ctx,
                head.optimizer_state(),
                &h.adam,
                &expected,
                "head/adam",
                &corrupt,
            )?;
            m.dictionary.restore(head);
        }

        for record in saved.history {
            m.history.push(record);
        }
        for ((stamp_ns, _), gain) in saved.trajectory.iter().zip(saved.exposure) {
            m.exposure.push(*stamp_ns, gain);
        }
        m.trajectory = saved.trajectory;

        // Window: the same residents in the same rows, with their Adam
        // state.
        if let Some(w) = saved.window {
            let dim = m.dictionary.head().map(|h| h.config().dim);
            m.ensure_workspace(w.view_pixels, dim)?;
            // Every resident is in the map, its block in memory.
            let global = m.pager.global_mut();
            for &key in &w.keys {
                global.load(GlobalMap::block_of(key))?;
                if !global.contains(key) {
                    return Err(corrupt(format!("window voxel {key:?} is not in the map")));
                }
            }
            let trainer = m
                .trainer
                .as_ref()
                .ok_or_else(|| corrupt("no trainer for the window".into()))?;
            m.pager.append(ctx, &w.keys, &trainer.window_rows())?;
            let rows = w.keys.len() as u64;
            let buffers = trainer.optimizer().state();
            let expected: Vec<u64> = buffers.iter().map(|(_, row)| rows * row).collect();
            upload_state(ctx, buffers, &w.state, &expected, "window/state", &corrupt)?;
        }
        Ok(m)
    }
}

/// Uploads saved optimiser tensors into `buffers`, each of exactly
/// `expected` bytes (`what` names them in errors).
fn upload_state(
    ctx: &Context,
    buffers: Vec<(&Buffer, u64)>,
    saved: &[Vec<u8>],
    expected: &[u64],
    what: &str,
    corrupt: &dyn Fn(String) -> Error,
) -> Result<()> {
    if buffers.len() != saved.len() {
        return Err(corrupt(format!(
            "{} {what} tensors; this build has {}",
            saved.len(),
            buffers.len()
        )));
    }
    for (i, (((buf, _), bytes), &want)) in buffers.into_iter().zip(saved).zip(expected).enumerate()
    {
        if bytes.len() as u64 != want {
            return Err(corrupt(format!(
                "{what}/{i} holds {} bytes, {want} expected",
                bytes.len()
            )));
        }
        ctx.upload(buf, 0, bytes)?;
    }
    Ok(())
}

/// The error that refuses to save a diverged map: loading refuses
/// non-finite values, so refusing them here too keeps a diverged map from
/// replacing a good save.
fn diverged(path: &Path, why: String) -> Error {
    Error::damaged(
        path,
        format!("the map has diverged and is not saved (it would not load): {why}"),
    )
}

/// A live mapper's global map as a save writes it: block by block, spilled
/// blocks read from disk one at a time, each Gaussian checked finite.
struct LiveRows<'a> {
    global: &'a GlobalMap,
    seeder: &'a Seeder,
    /// The file being written (names it in errors).
    path: &'a Path,
}

impl MapRows for LiveRows<'_> {
    fn len(&self) -> usize {
        self.global.len()
    }

    fn for_each_chunk(&self, visit: &mut ChunkVisitor<'_>) -> Result<()> {
        let mut flags = Vec::new();
        self.global.for_each_block(|_, keys, gaussians| {
            flags.clear();
            for (key, g) in keys.iter().zip(gaussians) {
                let values: &[f32] = bytemuck::cast_slice(std::slice::from_ref(g));
                if !values.iter().all(|x| x.is_finite()) {
                    let why = format!("the Gaussian of voxel {key:?} is not finite");
                    return Err(diverged(self.path, why));
                }
                flags.push(if self.seeder.is_superseded(key) {
                    SUPERSEDED
                } else {
                    GUESSED * self.seeder.is_guess(key) as u8
                });
            }
            visit(keys, gaussians, &flags)
        })
    }
}

/// Refuses to save a diverged latent head or window (see [`diverged`]).
fn check_finite(path: &Path, head: Option<&SavedHead>, window: Option<&SavedWindow>) -> Result<()> {
    if let Some(h) = head {
        for (name, v) in [
            ("head/W", &h.w),
            ("head/D", &h.atoms),
            ("head/D0", &h.anchors),
        ] {
            finite(v, name).map_err(|why| diverged(path, why))?;
        }
        for (i, t) in h.adam.iter().enumerate().filter(|(i, _)| i % 3 != 2) {
            finite_bytes(t, &format!("head/adam/{i}")).map_err(|why| diverged(path, why))?;
        }
    }
    if let Some(w) = window {
        for (i, t) in w.state.iter().enumerate().filter(|(i, _)| i % 3 != 2) {
            finite_bytes(t, &format!("window/state/{i}")).map_err(|why| diverged(path, why))?;
        }
    }
    Ok(())
}
