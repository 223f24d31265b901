//! One keyframe's optimisation (paper Alg. 1, lines 5–6): Stage I renders
//! a batch of keyframes from the window's Gaussians and takes one joint
//! Adam step on the Gaussians, W and D; Stage II takes further steps on W
//! and D from the region queries Stage I pooled (the Gaussians are frozen,
//! so those queries stay valid).

use super::history::KeyframeRecord;
use crate::error::{Error, Result};
use crate::gpu::{Buffer, Context, GpuSpan, Readback, Submission};
use crate::latent::{LabelImage, LatentHead, RegionPooling, Regions};
use crate::loss::{mean_per_view_weights, FeatureLoss, ImageLoss, ImageLossValues, LossWeights};
use crate::map::LocalWindow;
use crate::optim::{GaussianLearningRates, GaussianOptimizer};
use crate::splat::{Camera, ForwardStats, GaussianBuffers, Rasterizer};

/// Sizes of the trainer's workspace.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrainerConfig {
    /// Window capacity (Gaussians).
    pub capacity: u64,
    /// Largest view (pixels).
    pub max_view_pixels: u64,
    /// Views per batch (the new keyframe + B).
    pub max_views: u32,
    /// Regions per batch.
    pub max_regions: u32,
    /// Regions covering fewer pixels in a view are ignored.
    pub min_region_pixels: u32,
    /// Loss weights.
    pub weights: LossWeights,
    /// Gaussian learning rates.
    pub learning_rates: GaussianLearningRates,
}

/// What a Stage I step measured (before its update).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct StageOneReport {
    /// Weighted image losses (mean over views).
    pub image: ImageLossValues,
    /// Feature loss (weighted, summed over regions with per-view means).
    pub feature: f64,
    /// Regions in the batch.
    pub regions: u32,
    /// Rasterizer counts.
    pub raster: ForwardStats,
}

/// The Stage I / Stage II executor.
pub struct Trainer {
    cfg: TrainerConfig,
    raster: Rasterizer,
    image_loss: ImageLoss,
    pooling: RegionPooling,
    grads: GaussianBuffers,
    optimizer: GaussianOptimizer,
    target: Buffer,
    region_targets: Buffer,
    row_weights: Buffer,
    regions: u32,
}

impl Trainer {
    /// Workspace for `cfg`; `dim` is the embedding dimension.
    pub fn new(ctx: &Context, cfg: TrainerConfig, dim: u32) -> Result<Self> {
        let max_pixels = cfg.max_view_pixels * cfg.max_views as u64;
        let capacity = u32::try_from(cfg.capacity).map_err(|_| {
            Error::InvalidArgument(format!("window capacity {} too large", cfg.capacity))
        })?;
        Ok(Trainer {
            region_targets: Buffer::device(
                ctx,
                "trainer/region_targets",
                cfg.max_regions.max(1) as u64 * dim.max(1) as u64 * 4,
            )?,
            raster: Rasterizer::new(ctx),
            image_loss: ImageLoss::new(ctx, cfg.max_view_pixels, cfg.max_views, cfg.weights)?,
            pooling: RegionPooling::new(ctx, cfg.max_regions, max_pixels)?,
            grads: GaussianBuffers::new(ctx, "trainer/grads", cfg.capacity)?,
            optimizer: GaussianOptimizer::new(ctx, capacity, cfg.learning_rates)?,
            target: Buffer::device(ctx, "trainer/target_rgbd", max_pixels * 16)?,
            row_weights: Buffer::device(
                ctx,
                "trainer/row_weights",
                cfg.max_regions.max(1) as u64 * 4,
            )?,
            regions: 0,
            cfg,
        })
    }

    /// The Gaussian optimiser (its state moves with the window's rows).
    pub fn optimizer(&self) -> &GaussianOptimizer {
        &self.optimizer
    }

    /// The rasterizer (images of the last batch).
    pub fn rasterizer(&mut self) -> &mut Rasterizer {
        &mut self.raster
    }

    /// Stage I on `batch` (first the new keyframe): render, image and
    /// feature losses, backward through the decoder, pooling and
    /// rasterizer, one Adam step on the window's Gaussians and on W and D.
    /// Without a head (no embeddings seen yet) only the image losses train
    /// the Gaussians. Requires a non-empty dictionary when any keyframe has
    /// regions.
    pub fn stage_one(
        &mut self,
        ctx: &Context,
        window: &LocalWindow,
        head: Option<&LatentHead>,
        batch: &[&KeyframeRecord],
    ) -> Result<StageOneReport> {
        if batch.is_empty() || batch.len() > self.cfg.max_views as usize {
            return Err(Error::InvalidArgument(format!(
                "a batch of {} keyframes; between 1 and {} allowed",
                batch.len(),
                self.cfg.max_views
            )));
        }
        let count = window.len() as u64;
        let cameras: Vec<Camera> = batch.iter().map(|k| k.camera).collect();
        let raster_stats = self.raster.forward(window.params(), count, &cameras)?;
        let layout = self.raster.layout().clone();

        // Targets in batch pixel order.
        let mut target: Vec<[f32; 4]> = Vec::with_capacity(layout.pixels as usize);
        let mut valid = Vec::with_capacity(batch.len());
        for k in batch {
            target.extend(k.target_rgbd());
            valid.push(k.valid_depth() as u64);
        }
        // Regions and their target rows.
        let mut regions = Regions::new(&layout, self.cfg.min_region_pixels);
        let mut rows: Vec<f32> = Vec::new();
        let dim = head.map_or(0, |h| h.config().dim as usize);
        for (v, k) in batch.iter().enumerate() {
            let (Some(r), Some(_)) = (&k.regions, head) else {
                continue;
            };
            if r.dim as usize != dim {
                return Err(Error::InvalidArgument(format!(
                    "keyframe at {} ns has {}-d embeddings; the head is {dim}-d",
                    k.stamp_ns, r.dim
                )));
            }
            let view = if r.grid {
                regions.add_grid(v, r.height, r.width)?
            } else {
                regions.add_labels(
                    v,
                    LabelImage {
                        width: r.width,
                        height: r.height,
                        labels: &r.labels,
                    },
                    r.count,
                )?
            };
            for &s in &view.sources {
                rows.extend_from_slice(&r.vectors[s as usize * dim..(s as usize + 1) * dim]);
            }
        }
        let n = regions.len();
        if n > self.cfg.max_regions {
            return Err(Error::InvalidArgument(format!(
                "batch has {n} regions; the trainer holds {}",
                self.cfg.max_regions
            )));
        }
        let mut weights = mean_per_view_weights(&regions.rows_per_view());
        for (w, row) in weights.iter_mut().zip(rows.chunks(dim.max(1))) {
            if row.iter().all(|&x| x == 0.0) {
                *w = 0.0;
            }
        }
        self.regions = n;

        let images = self.raster.images()?;
        let image_grads = self.raster.image_grads()?;
        let region_targets = &self.region_targets;
        let mut rec = ctx.recorder()?;
        rec.upload(&self.target, 0, &target)?;
        self.image_loss.record(
            &mut rec,
            &layout,
            &images.rgbd,
            &self.target,
            &valid,
            &image_grads.rgbd,
        )?;
        rec.fill_u32(&image_grads.alpha, 0);
        let mut feature_readback = None;
        if let (true, Some(head)) = (n > 0, head) {
            rec.upload(region_targets, 0, &rows)?;
            rec.upload(&self.row_weights, 0, &weights)?;
            self.pooling.record_upload(&mut rec, &regions)?;
            self.pooling.record_forward(&mut rec, &images.query)?;
            head.record_step(
                &mut rec,
                self.pooling.pooled(),
                region_targets,
                &self.row_weights,
                n,
                true,
            )?;
            feature_readback = Some(head.record_loss_readback(&mut rec, n)?.0);
            self.pooling
                .record_backward(&mut rec, head.grad_queries(), &image_grads.query)?;
        } else {
            rec.fill_u32(&image_grads.query, 0);
        }
        let image_readback = self.image_loss.record_readback(&mut rec)?;
        self.raster
            .record_backward(&mut rec, window.params(), &self.grads)?;
        self.optimizer
            .record_step(&mut rec, window.params(), &self.grads, count as u32, None)?;
        rec.submit()?.wait()?;
        Ok(StageOneReport {
            image: image_readback.values()?,
            feature: match feature_readback {
                Some(r) => FeatureLoss::sum(&r)?,
                None => 0.0,
            },
            regions: n,
            raster: raster_stats,
        })
    }

    /// Stage II: `iterations` steps on W and D from the region queries of
    /// the last Stage I; returns the feature loss of the last step (before
    /// its update). Nothing to do when the batch had no regions.
    pub fn stage_two(
        &self,
        ctx: &Context,
        head: Option<&LatentHead>,
        iterations: u32,
    ) -> Result<f64> {
        Ok(self.submit_stage_two(ctx, head, iterations)?.finish()?.0)
    }

    /// [`Trainer::stage_two`] without waiting: the work is submitted (and
    /// timed) on the compute queue, so paging can run beside it.
    pub fn submit_stage_two(
        &self,
        ctx: &Context,
        head: Option<&LatentHead>,
        iterations: u32,
    ) -> Result<StageTwoRun> {
        let n = self.regions;
        let Some(head) = head else {
            return Ok(StageTwoRun(None));
        };
        if n == 0 || iterations == 0 {
            return Ok(StageTwoRun(None));
        }
        let region_targets = &self.region_targets;
        let mut rec = ctx.recorder()?;
        rec.start_span();
        let mut last = None;
        for i in 0..iterations {
            head.record_step(
                &mut rec,
                self.pooling.pooled(),
                region_targets,
                &self.row_weights,
                n,
                false,
            )?;
            if i + 1 == iterations {
                last = Some(head.record_loss_readback(&mut rec, n)?.0);
            }
        }
        let submission = rec.submit()?;
        Ok(StageTwoRun(Some((
            submission,
            last.expect("at least one iteration"),
        ))))
    }
}

/// A submitted Stage II.
#[must_use = "Stage II must be finished"]
pub struct StageTwoRun(Option<(Submission, Readback)>);

impl StageTwoRun {
    /// Waits; returns the feature loss of the last step and when the work
    /// ran on the GPU (when it could be timed).
    pub fn finish(self) -> Result<(f64, Option<GpuSpan>)> {
        match self.0 {
            None => Ok((0.0, None)),
            Some((submission, readback)) => {
                let span = submission.wait_span()?;
                Ok((FeatureLoss::sum(&readback)?, span))
            }
        }
    }
}
