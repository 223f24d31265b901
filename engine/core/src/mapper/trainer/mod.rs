//! One keyframe's optimisation (paper Alg. 1, lines 5–6): Stage I renders
//! a batch of keyframes from the window's Gaussians (streamed in chunks of
//! views, so image memory is bounded by one chunk) and takes one joint
//! Adam step on the Gaussians, W and D; Stage II takes further steps on W
//! and D from the region queries Stage I pooled (the Gaussians are frozen,
//! so those queries stay valid).

use std::collections::HashMap;
use std::sync::Arc;

use super::history::{KeyframeRecord, RegionTargets, ReplayKey};
use crate::latent::{LatentHead, RegionCounts, RegionPooling, RegionRows};
use crate::loss::{mean_per_view_weights, FeatureLoss, ImageLoss, ImageLossValues, LossWeights};
use crate::map::Companion;
use crate::map::LocalWindow;
use crate::optim::{GaussianLearningRates, GaussianOptimizer};
use crate::splat::{
    BatchLayout, Camera, Channels, ForwardStats, GaussianBuffers, QueryGradients, Rasterizer,
    QUERY_DIM,
};
use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context};

mod kept_targets;

pub(crate) use kept_targets::slot_bytes as kept_target_bytes;
pub use kept_targets::{ChunkView, KeptTargets, Outputs};

/// Pixels Stage I renders at once by default: a batch larger than this is
/// streamed through the rasterizer in chunks of whole views, so the
/// memory for images does not grow with the replayed views (one 1280×720
/// view is a chunk of its own; six 320×240 views make one chunk).
pub const DEFAULT_CHUNK_PIXELS: u64 = 1 << 20;

/// Sizes of the trainer's workspace.
///
/// ```
/// use latentam_core::loss::LossWeights;
/// use latentam_core::mapper::{TrainerConfig, DEFAULT_CHUNK_PIXELS};
/// use latentam_core::optim::GaussianLearningRates;
/// use latentam_core::splat::BlendLayout;
///
/// let cfg = TrainerConfig {
///     capacity: 200_000, max_view_pixels: 640 * 480, max_views: 8,
///     chunk_pixels: DEFAULT_CHUNK_PIXELS, max_regions: 2048, min_region_pixels: 16,
///     weights: LossWeights::default(), learning_rates: GaussianLearningRates::default(),
///     attach_feature_gradients: false, blend_layout: BlendLayout::Auto,
///     kept_views: 32,
/// };
/// assert_eq!(cfg.views_per_chunk(), 3); // 2^20 pixels hold three 640×480 views
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrainerConfig {
    /// Window capacity (Gaussians).
    pub capacity: u64,
    /// Largest view (pixels).
    pub max_view_pixels: u64,
    /// Views per batch (the new keyframe + B).
    pub max_views: u32,
    /// Pixels rendered at once (at least one view is; see
    /// [`DEFAULT_CHUNK_PIXELS`]).
    pub chunk_pixels: u64,
    /// Regions per batch.
    pub max_regions: u32,
    /// Regions covering fewer pixels in a view are ignored.
    pub min_region_pixels: u32,
    /// Loss weights.
    pub weights: LossWeights,
    /// Gaussian learning rates.
    pub learning_rates: GaussianLearningRates,
    /// The feature loss reaches opacity and geometry, not only the
    /// queries (Stage I renders query images).
    pub attach_feature_gradients: bool,
    /// The blending kernels' layout (see [`BlendLayout`](crate::splat::BlendLayout)).
    pub blend_layout: crate::splat::BlendLayout,
    /// Keyframes whose colour, depth and region rows stay on the GPU
    /// between steps ([`KeptTargets`]; at least one slot is made; 0 keeps
    /// none, whatever keys a batch brings).
    pub kept_views: u32,
}

impl TrainerConfig {
    /// Views rendered at once: as many of the largest views as fit
    /// [`TrainerConfig::chunk_pixels`], at least one, at most a batch.
    pub fn views_per_chunk(&self) -> u32 {
        views_per_chunk(self.max_view_pixels, self.max_views, self.chunk_pixels)
    }
}

/// Views of `view_pixels` pixels rendered at once when batches of
/// `max_views` views are streamed in chunks of at most `chunk_pixels`.
pub fn views_per_chunk(view_pixels: u64, max_views: u32, chunk_pixels: u64) -> u32 {
    let fit = chunk_pixels / view_pixels.max(1);
    fit.clamp(1, max_views.max(1) as u64) as u32
}

/// What a Stage I step measured (before its update).
///
/// ```no_run
/// # use latentam_gpu::Context; use latentam_core::{latent::LatentHead, map::LocalWindow};
/// # use latentam_core::mapper::{KeyframeRecord, Trainer};
/// # fn f(ctx: &Context, trainer: &mut Trainer, window: &LocalWindow, head: &LatentHead, batch: &[&KeyframeRecord]) -> latentam_core::Result<()> {
/// let report = trainer.stage_one(ctx, window, Some(head), batch, &[])?;
/// println!(
///     "image loss {:.4}, feature loss {:.4} over {} regions, {} visible pairs",
///     report.image.total(), report.feature, report.regions, report.raster.visible
/// );
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct StageOneReport {
    /// Weighted image losses (mean over views).
    pub image: ImageLossValues,
    /// Feature loss (weighted, summed over regions with per-view means).
    pub feature: f64,
    /// Regions in the batch.
    pub regions: u32,
    /// Rasterizer counts (summed over the batch's views).
    pub raster: ForwardStats,
    /// Chunks of views the batch was rendered in.
    pub chunks: u32,
    /// Forward passes rendered (chunks with regions are rendered twice
    /// when the batch takes more than one chunk: once to pool their
    /// queries before the decoder's step, once to differentiate them).
    pub forward_passes: u32,
}

/// One chunk of a Stage I batch: consecutive views rendered together.
struct Chunk {
    views: std::ops::Range<usize>,
    layout: BatchLayout,
    /// The chunk's regions, numbered from 0 within the chunk.
    regions: Option<RegionRows>,
    /// Row of the chunk's first region among the batch's pooled rows.
    first_row: u32,
}

/// The Stage I / Stage II executor.
///
/// ```no_run
/// # use latentam_gpu::Context; use latentam_core::{latent::LatentHead, map::LocalWindow};
/// # use latentam_core::mapper::{KeyframeRecord, TrainerConfig};
/// # fn f(ctx: &Context, cfg: TrainerConfig, window: &LocalWindow, head: &LatentHead, keyframe: &KeyframeRecord, replayed: &[&KeyframeRecord]) -> latentam_core::Result<()> {
/// use latentam_core::mapper::Trainer;
///
/// let mut trainer = Trainer::new(ctx, cfg, head.config().dim)?;
/// let mut batch = vec![keyframe]; // the new keyframe first, then past ones
/// batch.extend_from_slice(replayed);
/// let stage_one = trainer.stage_one(ctx, window, Some(head), &batch, &[])?;
/// let feature_loss = trainer.stage_two(ctx, Some(head), 10)?;
/// # Ok(())
/// # }
/// ```
pub struct Trainer {
    cfg: TrainerConfig,
    raster: Rasterizer,
    image_loss: ImageLoss,
    pooling: RegionPooling,
    grads: GaussianBuffers,
    optimizer: GaussianOptimizer,
    target: Buffer,
    kept: KeptTargets,
    region_targets: Buffer,
    row_weights: Buffer,
    regions: u32,
    /// Each keyframe's regions counted when it first trained, by key: a
    /// keyframe's regions never change, and replays count them no more.
    counted: HashMap<ReplayKey, Arc<RegionCounts>>,
}

/// Keyframes whose region counts [`Trainer`] keeps (a few kB each); past
/// it, only those of the batch in hand are kept.
const COUNTED_KEYFRAMES: usize = 4096;

impl Trainer {
    /// Workspace for `cfg`; `dim` is the embedding dimension (the region
    /// targets grow if a batch brings larger ones).
    pub fn new(ctx: &Context, cfg: TrainerConfig, dim: u32) -> Result<Self> {
        let chunk_views = cfg.views_per_chunk();
        let max_pixels = cfg.max_view_pixels * chunk_views as u64;
        let capacity = u32::try_from(cfg.capacity).map_err(|_| {
            Error::bad_input(
                "window capacity",
                format!("{} too large (at most {})", cfg.capacity, u32::MAX),
            )
        })?;
        Ok(Trainer {
            region_targets: Buffer::device(
                ctx,
                "trainer/region_targets",
                cfg.max_regions.max(1) as u64 * dim.max(1) as u64 * 4,
            )?,
            raster: {
                let mut r = Rasterizer::new(ctx);
                r.settings.query_gradient_image = false;
                r.settings.detach_query_gradients = !cfg.attach_feature_gradients;
                r.settings.layout = cfg.blend_layout;
                r
            },
            image_loss: ImageLoss::new(ctx, cfg.max_view_pixels, chunk_views, cfg.weights)?,
            pooling: RegionPooling::new(ctx, cfg.max_regions, max_pixels)?,
            grads: GaussianBuffers::new(ctx, "trainer/grads", cfg.capacity)?,
            optimizer: GaussianOptimizer::new(ctx, capacity, cfg.learning_rates)?,
            target: Buffer::device(ctx, "pixels/target_rgbd", max_pixels * 16)?,
            kept: KeptTargets::new(ctx, cfg.kept_views, cfg.max_view_pixels)?,
            row_weights: Buffer::device(
                ctx,
                "trainer/row_weights",
                cfg.max_regions.max(1) as u64 * 4,
            )?,
            regions: 0,
            counted: HashMap::new(),
            cfg,
        })
    }

    /// The workspace's sizes.
    pub fn config(&self) -> &TrainerConfig {
        &self.cfg
    }

    /// The Gaussian optimiser (its state moves with the window's rows).
    pub fn optimizer(&self) -> &GaussianOptimizer {
        &self.optimizer
    }

    /// The keyframe targets kept on the GPU.
    pub fn kept_targets(&self) -> &KeptTargets {
        &self.kept
    }

    /// The optimiser's per-row state, which moves with the window's rows
    /// when it pages.
    pub fn window_rows(&self) -> Vec<Companion<'_>> {
        self.optimizer
            .state()
            .into_iter()
            .map(|(buffer, row_bytes)| Companion { buffer, row_bytes })
            .collect()
    }

    /// Gradients of the last Stage I step, summed over its batch.
    pub fn gradients(&self) -> &GaussianBuffers {
        &self.grads
    }

    /// The rasterizer (images of the last chunk rendered; after a Stage I
    /// step that is the chunk holding the new keyframe, as view 0, its query
    /// channels possibly not rendered: see [`Rasterizer::channels`]).
    pub fn rasterizer(&mut self) -> &mut Rasterizer {
        &mut self.raster
    }

    /// Stage I on `batch` (first the new keyframe): render, image and
    /// feature losses, backward through the decoder, pooling and
    /// rasterizer, one Adam step on the window's Gaussians and on W and D.
    /// Without a head (no embeddings seen yet) only the image losses train
    /// the Gaussians. Requires a non-empty dictionary when any keyframe has
    /// regions.
    ///
    /// The batch is rendered in chunks of whole views (see
    /// [`TrainerConfig::chunk_pixels`]), so its images never need more
    /// memory than one chunk's. The decoder's step needs every region's
    /// pooled query first: chunks with regions are rendered and pooled,
    /// the decoder steps, and then each chunk is differentiated, with its
    /// gradients added to the batch's. The last chunk pooled is
    /// differentiated first, while its forward pass is still at hand; the
    /// others are rendered again. The step equals the one of the whole
    /// batch rendered at once, up to the order of float sums.
    ///
    /// Two host waits: one measures the batch (how many splats and tile
    /// intersections each chunk's rendering needs), one ends the step;
    /// everything between is one submission. [`Trainer::submit_stage_one`]
    /// leaves the second to the caller.
    ///
    /// `keys` names the batch's keyframes, in order, for [`KeptTargets`]:
    /// a keyframe whose targets are kept on the GPU under its key uploads
    /// nothing; one that is not is uploaded and kept. Empty: nothing is
    /// kept (every target is uploaded).
    pub fn stage_one(
        &mut self,
        ctx: &Context,
        window: &LocalWindow,
        head: Option<&LatentHead>,
        batch: &[&KeyframeRecord],
        keys: &[ReplayKey],
    ) -> Result<StageOneReport> {
        self.submit_stage_one(ctx, window, head, batch, keys)?
            .finish()
    }

    /// [`Trainer::stage_one`] without its last wait: the step is submitted,
    /// and its losses are read by [`SubmittedStageOne::finish`], which
    /// waits only if the step is not done by then (a later wait on the
    /// same queue, Stage II's, covers it).
    //
    // Why one long function: the recorder borrows the trainer's buffers
    // (rasterizer images, pooled rows, gradients) until it is submitted,
    // so the two passes cannot be methods taking `&mut self` while it is
    // open; they are the two commented blocks below.
    pub fn submit_stage_one(
        &mut self,
        ctx: &Context,
        window: &LocalWindow,
        head: Option<&LatentHead>,
        batch: &[&KeyframeRecord],
        keys: &[ReplayKey],
    ) -> Result<SubmittedStageOne> {
        if !keys.is_empty() && keys.len() != batch.len() {
            return Err(Error::bad_input(
                "keyframe batch",
                format!("{} keys for {} keyframes", keys.len(), batch.len()),
            ));
        }
        if batch.is_empty() || batch.len() > self.cfg.max_views as usize {
            return Err(Error::bad_input(
                "keyframe batch",
                format!(
                    "a batch of {} keyframes; between 1 and {} allowed",
                    batch.len(),
                    self.cfg.max_views
                ),
            ));
        }
        let count = window.len() as u64;
        let dim = head.map_or(0, |h| h.config().dim as usize);
        let (chunks, rows, rows_per_view) = self.plan(batch, keys, head.is_some(), dim)?;
        let keys = if self.cfg.kept_views == 0 { &[] } else { keys };
        let n: u32 = rows_per_view.iter().sum();
        if n > self.cfg.max_regions {
            return Err(Error::bad_input(
                "keyframe batch",
                format!("{n} regions; the trainer holds {}", self.cfg.max_regions),
            ));
        }
        let mut weights = mean_per_view_weights(&rows_per_view);
        for (w, row) in weights.iter_mut().zip(rows.chunks(dim.max(1))) {
            if row.iter().all(|&x| x == 0.0) {
                *w = 0.0;
            }
        }
        self.regions = n;
        let mut report = StageOneReport {
            regions: n,
            chunks: chunks.len() as u32,
            ..Default::default()
        };

        // Detached query gradients need no rendered query image: the
        // rasterizer pools the queries into region rows itself, and the
        // backward pass reads neither.
        let channels = if self.raster.settings.detach_query_gradients {
            Channels::Colour
        } else {
            Channels::All
        };

        // Embeddings may first arrive after the workspace was sized.
        let target_bytes = (rows.len() * 4) as u64;
        if target_bytes > self.region_targets.bytes() {
            self.region_targets = Buffer::device(ctx, "trainer/region_targets", target_bytes)?;
        }

        // Every chunk is measured at once (the only host wait before the
        // end): the Gaussians do not change until the Adam step that ends
        // the recording, so the counts stay valid for both passes.
        let chunk_cameras: Vec<Vec<Camera>> = chunks
            .iter()
            .map(|c| batch[c.views.clone()].iter().map(|k| k.camera).collect())
            .collect();
        let camera_lists: Vec<&[Camera]> = chunk_cameras.iter().map(Vec::as_slice).collect();
        let sized = self
            .raster
            .measure(window.params(), count, &camera_lists, channels)?;
        for s in &sized {
            report.raster.visible += s.stats().visible;
            report.raster.intersections += s.stats().intersections;
        }
        let mut rec = ctx.recorder()?;

        // Pass 1: pool every chunk's regions, then the decoder's step.
        let head = head.filter(|_| n > 0);
        let mut live = None;
        let mut feature_readback = None;
        if let Some(head) = head {
            for (c, chunk) in chunks.iter().enumerate() {
                let Some(regions) = &chunk.regions else {
                    continue;
                };
                self.raster
                    .record_forward(&mut rec, window.params(), &sized[c])?;
                report.forward_passes += 1;
                self.pooling
                    .record_offsets_at(&mut rec, regions, chunk.first_row)?;
                for (v, i) in chunk.views.clone().enumerate() {
                    let view = ChunkView {
                        record: batch[i],
                        key: keys.get(i).copied(),
                        view: v,
                        regions: Some(regions),
                    };
                    let out = Outputs {
                        target: None,
                        labels: Some(self.pooling.labels()),
                    };
                    self.kept
                        .record_expand(&mut rec, &chunk.layout, view, out)?;
                }
                let row_bytes = QUERY_DIM as u64 * 4;
                rec.fill_range_u32(
                    self.pooling.pooled(),
                    chunk.first_row as u64 * row_bytes,
                    regions.len() as u64 * row_bytes,
                    0,
                )?;
                self.raster.record_pool(
                    &mut rec,
                    &sized[c],
                    window.params(),
                    self.pooling.pooled(),
                    chunk.first_row,
                    self.pooling.labels(),
                    self.pooling.labels_offsets_at(),
                )?;
                live = Some(c);
            }
            rec.upload(&self.region_targets, 0, &rows)?;
            rec.upload(&self.row_weights, 0, &weights)?;
            head.record_step(
                &mut rec,
                self.pooling.pooled(),
                &self.region_targets,
                &self.row_weights,
                n,
                true,
            )?;
            feature_readback = Some(head.record_loss_readback(&mut rec, n)?.0);
        }

        // Pass 2: differentiate each chunk (the one still rendered first,
        // the new keyframe's last, so its images are what stays behind),
        // then one Adam step on the sum.
        let mut order: Vec<usize> = live.into_iter().collect();
        order.extend((0..chunks.len()).rev().filter(|&c| Some(c) != live));
        let mut image_readbacks = Vec::with_capacity(order.len());
        for (k, &c) in order.iter().enumerate() {
            let chunk = &chunks[c];
            if Some(c) != live || k > 0 {
                self.raster
                    .record_forward(&mut rec, window.params(), &sized[c])?;
                report.forward_passes += 1;
            }
            // The targets, and for a chunk pooled before the last one its
            // region rows again (the pooling holds one chunk's at a time).
            let relabel = match (&chunk.regions, head) {
                (Some(regions), Some(_)) if Some(c) != live => {
                    self.pooling
                        .record_offsets_at(&mut rec, regions, chunk.first_row)?;
                    true
                }
                _ => false,
            };
            let mut valid = Vec::with_capacity(chunk.views.len());
            for (v, i) in chunk.views.clone().enumerate() {
                let view = ChunkView {
                    record: batch[i],
                    key: keys.get(i).copied(),
                    view: v,
                    regions: chunk.regions.as_ref(),
                };
                let out = Outputs {
                    target: Some(&self.target),
                    labels: relabel.then(|| self.pooling.labels()),
                };
                self.kept
                    .record_expand(&mut rec, &chunk.layout, view, out)?;
                valid.push(batch[i].valid_depth() as u64);
            }
            let images = self.raster.images()?;
            let image_grads = self.raster.image_grads()?;
            self.image_loss.record_part(
                &mut rec,
                &chunk.layout,
                &images.rgbd,
                &self.target,
                &valid,
                &image_grads.rgbd,
                batch.len(),
            )?;
            rec.fill_u32(&image_grads.alpha, 0);
            // The pooled rows' gradients reach each pixel through its
            // region, with no per-pixel query gradient image.
            let query = match (&chunk.regions, head) {
                (Some(_), Some(head)) => {
                    // The last chunk pooled still has its rows in place;
                    // the others were written again above.
                    QueryGradients::Regions {
                        rows: head.grad_queries(),
                        first_row: chunk.first_row,
                        labels: self.pooling.labels(),
                        offsets_at: self.pooling.labels_offsets_at(),
                    }
                }
                _ => QueryGradients::Zero,
            };
            image_readbacks.push(self.image_loss.record_readback(&mut rec)?);
            self.raster.record_backward_into(
                &mut rec,
                &sized[c],
                window.params(),
                &self.grads,
                k > 0,
                query,
            )?;
            if k + 1 == order.len() {
                self.optimizer.record_step(
                    &mut rec,
                    window.params(),
                    &self.grads,
                    count as u32,
                    None,
                )?;
            }
        }
        Ok(SubmittedStageOne {
            submission: rec.submit()?,
            report,
            feature_readback,
            image_readbacks,
        })
    }

    /// Splits `batch` into chunks of whole views and gathers the regions:
    /// the chunks, every region's target row (batch order) and the pooled
    /// rows of each view.
    fn plan(
        &mut self,
        batch: &[&KeyframeRecord],
        keys: &[ReplayKey],
        has_head: bool,
        dim: usize,
    ) -> Result<(Vec<Chunk>, Vec<f32>, Vec<u32>)> {
        if self.counted.len() > COUNTED_KEYFRAMES {
            self.counted.retain(|k, _| keys.contains(k));
        }
        let mut chunks = Vec::new();
        let mut rows: Vec<f32> = Vec::new();
        let mut rows_per_view = vec![0u32; batch.len()];
        let mut next_row = 0u32;
        let mut start = 0;
        while start < batch.len() {
            // Whole views while they fit the chunk (at least one).
            let mut end = start + 1;
            let mut pixels = batch[start].camera.pixels();
            while end < batch.len() && pixels + batch[end].camera.pixels() <= self.cfg.chunk_pixels
            {
                pixels += batch[end].camera.pixels();
                end += 1;
            }
            let cams: Vec<Camera> = batch[start..end].iter().map(|k| k.camera).collect();
            let layout = BatchLayout::for_cameras(&cams)?;
            let mut regions = RegionRows::new(&layout);
            for (v, k) in batch[start..end].iter().enumerate() {
                let (Some(r), true) = (&k.regions, has_head) else {
                    continue;
                };
                if r.dim as usize != dim {
                    return Err(Error::EmbeddingDimension {
                        map: dim as u32,
                        given: r.dim,
                        context: Some(format!("the keyframe at {} ns", k.stamp_ns)),
                    });
                }
                let counts = self.counts(keys.get(start + v).copied(), k, r)?;
                let view = regions.add(v, &counts)?;
                rows_per_view[start + v] = view.sources.len() as u32;
                for &s in &view.sources {
                    rows.extend_from_slice(&r.vectors[s as usize * dim..(s as usize + 1) * dim]);
                }
            }
            let kept = regions.len();
            chunks.push(Chunk {
                views: start..end,
                layout,
                regions: (kept > 0).then_some(regions),
                first_row: next_row,
            });
            next_row += kept;
            start = end;
        }
        Ok((chunks, rows, rows_per_view))
    }

    /// The regions of `record` (whose targets are `targets`) counted: kept
    /// under `key` from the first time, when it has one.
    fn counts(
        &mut self,
        key: Option<ReplayKey>,
        record: &KeyframeRecord,
        targets: &RegionTargets,
    ) -> Result<Arc<RegionCounts>> {
        let count = || {
            RegionCounts::of(
                targets.source(),
                record.camera.width,
                record.camera.height,
                self.cfg.min_region_pixels,
            )
            .map(Arc::new)
        };
        let Some(key) = key else {
            return count();
        };
        if let Some(c) = self.counted.get(&key) {
            return Ok(c.clone());
        }
        let c = count()?;
        self.counted.insert(key, c.clone());
        Ok(c)
    }
}

/// A Stage I step submitted and not yet waited for
/// ([`Trainer::submit_stage_one`]).
#[must_use = "finish it to read its losses"]
pub struct SubmittedStageOne {
    submission: latentam_gpu::Submission,
    report: StageOneReport,
    feature_readback: Option<latentam_gpu::Readback>,
    image_readbacks: Vec<crate::loss::ImageLossReadback>,
}

impl SubmittedStageOne {
    /// The step's report, its losses read back: a host wait only when the
    /// step is still running.
    pub fn finish(self) -> Result<StageOneReport> {
        let SubmittedStageOne {
            submission,
            mut report,
            feature_readback,
            image_readbacks,
        } = self;
        submission.finished_span()?;
        if let Some(readback) = feature_readback {
            report.feature = FeatureLoss::sum(&readback)?;
        }
        for readback in image_readbacks {
            let v = readback.values()?;
            report.image.l1 += v.l1;
            report.image.ssim += v.ssim;
            report.image.depth += v.depth;
        }
        Ok(report)
    }
}

// Stage II builds on this file; its run is exported by `mapper` itself,
// so that this file does not depend on the one below it.
pub(super) mod stage_two;
