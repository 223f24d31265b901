//! The per-keyframe loop (paper Alg. 1) over the pieces in `map`,
//! `latent` and the [`Trainer`].

use glam::DVec3;

use super::history::{History, KeyframeRecord};
use super::trainer::{StageOneReport, Trainer, TrainerConfig};
use crate::error::{Error, Result};
use crate::gpu::Context;
use crate::io::Frame;
use crate::latent::{LatentHead, LatentHeadConfig};
use crate::loss::LossWeights;
use crate::map::{
    seed_from_frame, Companion, GlobalMap, KeyframeConfig, KeyframeSelector, LocalWindow,
    SeedingConfig, SyncPlan, ViewCoverage,
};
use crate::optim::GaussianLearningRates;

/// Every setting of the mapper; defaults are the paper's values where it
/// gives them and SPEC §12's otherwise.
#[derive(Clone, Debug, PartialEq)]
pub struct MapperConfig {
    /// Voxel edge of the global map, metres (s_v).
    pub voxel_size: f64,
    /// Keyframe selection.
    pub keyframes: KeyframeConfig,
    /// Gaussian seeding.
    pub seeding: SeedingConfig,
    /// Gaussians the GPU window holds.
    pub window_capacity: u64,
    /// Radius of the local window around the camera, metres.
    pub window_radius: f64,
    /// Re-synchronise the window when the camera has moved this far since
    /// the last sync (new Gaussians are always brought in).
    pub sync_distance: f64,
    /// Past keyframes per Stage I batch (B).
    pub replay: u32,
    /// Stage II iterations per keyframe (R2).
    pub stage_two_iterations: u32,
    /// Dictionary size (K).
    pub atoms: u32,
    /// Softmax temperature.
    pub temperature: f32,
    /// Loss weights.
    pub weights: LossWeights,
    /// Gaussian learning rates.
    pub learning_rates: GaussianLearningRates,
    /// Learning rate of W and D.
    pub latent_lr: f32,
    /// Regions per batch (all views).
    pub max_regions: u32,
    /// Regions smaller than this (pixels) are ignored.
    pub min_region_pixels: u32,
    /// Prune every this many keyframes (0 = never).
    pub prune_interval: u32,
    /// Gaussians less opaque than this are pruned (GS-ICP's 0.005).
    pub prune_min_opacity: f32,
    /// Gaussians with a standard deviation above this (metres) are pruned
    /// (GS-ICP's 0.1 × scene extent, for a 5 m indoor extent).
    pub prune_max_scale: f32,
    /// Seed of every random choice (W init, queries, replay sampling).
    pub seed: u64,
}

impl Default for MapperConfig {
    fn default() -> Self {
        MapperConfig {
            voxel_size: 0.01,
            keyframes: KeyframeConfig::default(),
            seeding: SeedingConfig::default(),
            window_capacity: 200_000,
            window_radius: 6.0,
            sync_distance: 0.5,
            replay: 5,
            stage_two_iterations: 5,
            atoms: 2000,
            temperature: 0.05,
            weights: LossWeights::default(),
            learning_rates: GaussianLearningRates::default(),
            latent_lr: 0.01,
            max_regions: 2048,
            min_region_pixels: 16,
            prune_interval: 10,
            prune_min_opacity: 0.005,
            prune_max_scale: 0.5,
            seed: 0,
        }
    }
}

/// What [`OnlineMapper::integrate`] did with a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Integrated {
    /// Not a keyframe.
    Skipped,
    /// A keyframe: Gaussians added and Stage I's measurements.
    Keyframe {
        /// New Gaussians.
        added: usize,
        /// Stage I of this keyframe.
        stage_one: StageOneReport,
        /// Feature loss of the last Stage II iteration.
        stage_two: f64,
        /// Gaussians pruned after this keyframe.
        pruned: usize,
    },
}

/// The online mapper's state.
pub struct OnlineMapper {
    ctx: Context,
    cfg: MapperConfig,
    global: GlobalMap,
    window: LocalWindow,
    selector: KeyframeSelector,
    history: History,
    head: Option<LatentHead>,
    trainer: Option<Trainer>,
    last_sync: Option<DVec3>,
    keyframes: u64,
}

impl OnlineMapper {
    /// An empty map on `ctx`.
    pub fn new(ctx: &Context, cfg: MapperConfig) -> Result<Self> {
        if !(cfg.voxel_size > 0.0 && cfg.voxel_size.is_finite()) {
            return Err(Error::InvalidArgument(format!(
                "voxel size {} must be positive",
                cfg.voxel_size
            )));
        }
        Ok(OnlineMapper {
            ctx: ctx.clone(),
            global: GlobalMap::new(cfg.voxel_size),
            window: LocalWindow::new(ctx, cfg.window_capacity)?,
            selector: KeyframeSelector::new(cfg.keyframes),
            history: History::default(),
            head: None,
            trainer: None,
            last_sync: None,
            keyframes: 0,
            cfg,
        })
    }

    /// The global map (current up to the last window sync).
    pub fn global(&self) -> &GlobalMap {
        &self.global
    }

    /// The GPU window.
    pub fn window(&self) -> &LocalWindow {
        &self.window
    }

    /// The latent head, once a frame with embeddings has been seen.
    pub fn head(&self) -> Option<&LatentHead> {
        self.head.as_ref()
    }

    /// The keyframes so far.
    pub fn history(&self) -> &History {
        &self.history
    }

    fn ensure_trainer(&mut self, frame: &Frame, dim: u32) -> Result<()> {
        let pixels = frame.color.width as u64 * frame.color.height as u64;
        if self.trainer.is_none() {
            self.trainer = Some(Trainer::new(
                &self.ctx,
                TrainerConfig {
                    capacity: self.cfg.window_capacity,
                    max_view_pixels: pixels,
                    max_views: self.cfg.replay + 1,
                    max_regions: self.cfg.max_regions,
                    min_region_pixels: self.cfg.min_region_pixels,
                    weights: self.cfg.weights,
                    learning_rates: self.cfg.learning_rates,
                },
                dim.max(1),
            )?);
        }
        Ok(())
    }

    /// Integrates one frame: keyframe selection, then for a keyframe the
    /// dictionary update, Gaussian seeding, window sync, Stage I over the
    /// keyframe and B past ones, Stage II, and the history append.
    pub fn integrate(&mut self, frame: &Frame) -> Result<Integrated> {
        if !self.selector.decide(frame, &self.global).keyframe {
            return Ok(Integrated::Skipped);
        }
        let record = KeyframeRecord::from_frame(frame);
        let seed = self.cfg.seed ^ self.keyframes.wrapping_mul(0x9e37_79b9);

        // Dictionary update from the keyframe's region embeddings.
        if let Some(r) = &record.regions {
            if self.head.is_none() {
                self.head = Some(LatentHead::new(
                    &self.ctx,
                    LatentHeadConfig {
                        dim: r.dim,
                        atoms: self.cfg.atoms,
                        max_regions: self.cfg.max_regions,
                        temperature: self.cfg.temperature,
                        lr_w: self.cfg.latent_lr,
                        lr_d: self.cfg.latent_lr,
                        weights: self.cfg.weights,
                        seed: self.cfg.seed,
                        ..Default::default()
                    },
                )?);
            }
            let head = self.head.as_ref().expect("created above");
            if head.config().dim != r.dim {
                return Err(Error::InvalidArgument(format!(
                    "keyframe embeddings are {}-d, the map's are {}-d",
                    r.dim,
                    head.config().dim
                )));
            }
            let rows: Vec<f32> = r
                .vectors
                .chunks(r.dim as usize)
                .filter(|row| row.iter().any(|&x| x != 0.0))
                .flatten()
                .copied()
                .collect();
            if !rows.is_empty() {
                let mut rec = self.ctx.recorder()?;
                head.record_keyframe_update(&mut rec, &rows)?;
                rec.submit()?.wait()?;
            }
        }
        let dim = self.head.as_ref().map_or(1, |h| h.config().dim);
        self.ensure_trainer(frame, dim)?;

        // What the map already explains at this pose, then new Gaussians.
        let coverage = if self.window.is_empty() {
            None
        } else {
            let raster = self.trainer.as_mut().expect("ensured").rasterizer();
            raster.forward(
                self.window.params(),
                self.window.len() as u64,
                &[record.camera],
            )?;
            Some(raster.download_alpha_depth(0)?)
        };
        let seeds = seed_from_frame(
            frame,
            coverage
                .as_ref()
                .map(|(alpha, depth)| ViewCoverage { alpha, depth }),
            &self.global,
            &self.cfg.seeding,
            seed,
        );
        let added = seeds
            .into_iter()
            .filter_map(|g| self.global.insert(g))
            .count();

        // Window sync when there is something new or the camera moved.
        let centre = frame.pose.translation;
        let moved = self
            .last_sync
            .is_none_or(|p| p.distance(centre) > self.cfg.sync_distance);
        if added > 0 || moved {
            let plan = self
                .window
                .plan(&self.global, centre, self.cfg.window_radius);
            self.sync_window(&plan)?;
            self.last_sync = Some(centre);
        }

        // Stage I on the keyframe and B past ones, then Stage II.
        let picks = self.history.sample(self.cfg.replay as usize, seed);
        let mut batch: Vec<&KeyframeRecord> = vec![&record];
        batch.extend(picks.iter().filter_map(|&i| self.history.get(i)));
        let trainer = self.trainer.as_mut().expect("ensured");
        let stage_one = trainer.stage_one(&self.ctx, &self.window, self.head.as_ref(), &batch)?;
        let stage_two =
            trainer.stage_two(&self.ctx, self.head.as_ref(), self.cfg.stage_two_iterations)?;
        self.history.push(record);
        self.keyframes += 1;
        let interval = self.cfg.prune_interval as u64;
        let pruned = if interval > 0 && self.keyframes % interval == 0 {
            self.prune()?
        } else {
            0
        };
        Ok(Integrated::Keyframe {
            added,
            stage_one,
            stage_two,
            pruned,
        })
    }

    /// Pages the window as `plan` says, moving the Gaussian optimiser's
    /// state with its rows, and writes the window back to the global map.
    fn sync_window(&mut self, plan: &SyncPlan) -> Result<()> {
        let trainer = self
            .trainer
            .as_ref()
            .expect("the trainer exists before the first sync");
        let companions: Vec<Companion<'_>> = trainer
            .optimizer()
            .state()
            .into_iter()
            .map(|(buffer, row_bytes)| Companion { buffer, row_bytes })
            .collect();
        let mut rec = self.ctx.transfer_recorder()?;
        let pending = self
            .window
            .record_sync(&mut rec, plan, &self.global, &companions)?;
        rec.submit()?.wait()?;
        pending.apply(&mut self.global)?;
        Ok(())
    }

    /// Removes the resident Gaussians that are nearly transparent or too
    /// large ([`MapperConfig::prune_min_opacity`], `prune_max_scale`) from
    /// the window and the global map, after writing the window back.
    /// Returns how many were removed.
    pub fn prune(&mut self) -> Result<usize> {
        let n = self.window.len();
        if n == 0 {
            return Ok(0);
        }
        let host = self.window.params().download(&self.ctx, n as u64)?;
        let min_logit = {
            let o = self.cfg.prune_min_opacity.clamp(1e-7, 1.0 - 1e-7);
            (o / (1.0 - o)).ln()
        };
        let max_log_scale = self.cfg.prune_max_scale.max(1e-9).ln();
        let evict: Vec<u32> = (0..n)
            .filter(|&i| {
                let o = host.opacity_logits[i];
                let s = host.log_scales[i].iter().copied().fold(f32::MIN, f32::max);
                // NaN parameters are pruned too.
                let keep = o >= min_logit && s <= max_log_scale;
                !keep
            })
            .map(|i| i as u32)
            .collect();
        if evict.is_empty() {
            return Ok(0);
        }
        let doomed: Vec<_> = evict
            .iter()
            .map(|&r| self.window.keys()[r as usize])
            .collect();
        let plan = SyncPlan {
            keep: n - evict.len(),
            evict,
            fetch: Vec::new(),
            over_capacity: 0,
        };
        self.sync_window(&plan)?;
        for key in &doomed {
            self.global.remove(*key);
        }
        Ok(doomed.len())
    }
}
