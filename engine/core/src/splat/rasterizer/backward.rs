//! The backward pass (`raster_backward` per pixel, replaying the forward
//! walk, then `project_backward` per Gaussian) and region pooling of the
//! rendered queries (`raster_pool`), which walks the same tile lists.

use super::work::BatchCounts;
use super::*;
use crate::splat::QUERY_DIM;
use latentam_shaders::bind;
use latentam_shaders::shared::{QUERY_GRAD_FROM_IMAGE, QUERY_GRAD_FROM_REGIONS, QUERY_GRAD_ZERO};

impl Rasterizer {
    /// Records the backward pass of the last forward batch: from the upstream
    /// gradients in [`Rasterizer::image_grads`] to `grads` (same layout as
    /// the parameters; Gaussians `0..count` of the forward pass are
    /// overwritten). `gaussians` must be unchanged since the forward pass.
    pub fn record_backward<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        gaussians: &'a GaussianBuffers,
        grads: &'a GaussianBuffers,
    ) -> Result<()> {
        let last = &self.last;
        self.record_backward_into(rec, last, gaussians, grads, false, QueryGradients::Image)
    }

    /// [`Rasterizer::record_backward`] that adds this batch's gradients to
    /// those already in `grads` when `accumulate` is set (a large batch
    /// rendered one chunk of views at a time then sums to the gradient of
    /// the whole batch, with images for one chunk only), and takes the
    /// upstream query gradients from `query`. `batch` is the batch whose
    /// forward pass was recorded last ([`Rasterizer::last_batch`] after
    /// [`Rasterizer::forward_channels`]).
    pub fn record_backward_into<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        batch: &RenderBatch,
        gaussians: &'a GaussianBuffers,
        grads: &'a GaussianBuffers,
        accumulate: bool,
        query: QueryGradients<'a>,
    ) -> Result<()> {
        let upstream = self.image_grads()?;
        let images = self.images()?;
        let stub = self.stub()?;
        let attached = !self.settings.detach_query_gradients;
        if attached && (batch.channels != Channels::All || images.query.is_none()) {
            return Err(Error::bad_input(
                "rendered batch",
                "query gradients reaching geometry need the rendered query: render with \
                 Channels::All",
            ));
        }
        let (source, first_row, grad_query, labels, offsets_at) = match query {
            QueryGradients::Image => (QUERY_GRAD_FROM_IMAGE, 0, upstream.query()?, stub, 0),
            QueryGradients::Regions {
                rows,
                first_row,
                labels,
                offsets_at,
            } => {
                Self::check_region_labels(batch, labels, offsets_at)?;
                (QUERY_GRAD_FROM_REGIONS, first_row, rows, labels, offsets_at)
            }
            QueryGradients::Zero => (QUERY_GRAD_ZERO, 0, stub, stub, 0),
        };
        let count = batch.count;
        if grads.capacity() < count || gaussians.capacity() < count {
            return Err(Error::bad_input(
                "gradient buffers",
                format!(
                    "backward over {count} Gaussians into buffers of capacity {}",
                    grads.capacity().min(gaussians.capacity())
                ),
            ));
        }
        let n_views = batch.layout.views.len() as u32;
        if !accumulate {
            rec.fill_u32(&grads.colors, 0);
            rec.fill_u32(&grads.queries, 0);
        }
        rec.fill_u32(self.grad_splats.get(), 0);
        let bg = self.settings.background;
        let p = push::RasterBackward {
            n_gaussians: count as u32,
            n_views,
            n_tiles: batch.layout.tiles,
            detach_query: self.settings.detach_query_gradients as u32,
            bg_r: bg[0],
            bg_g: bg[1],
            bg_b: bg[2],
            query_source: source,
            first_row,
            offsets_at,
        };
        let bufs = bind::RasterBackwardBuffers {
            views: self.views.get(),
            colors: &gaussians.colors,
            queries: &gaussians.queries,
            splats: self.splats.get(),
            pairs: self.isect_pairs.get(),
            ranges: self.ranges.get(),
            rgbd: &images.rgbd,
            query_image: images.query.as_ref().unwrap_or(stub),
            state: self.state.get(),
            grad_rgbd: &upstream.rgbd,
            grad_alpha: &upstream.alpha,
            grad_query,
            grad_colors: &grads.colors,
            grad_queries: &grads.queries,
            grad_splats: self.grad_splats.get(),
            pixel_region: labels,
        };
        let kernel = buildable(rec, &self.settings, |s| backward_kernel(rec.info(), s))?;
        let counts = BatchCounts::of(batch);
        let detach = self.settings.detach_query_gradients;
        let upstream_image = source == QUERY_GRAD_FROM_IMAGE;
        rec.work_of_next(counts.blend_backward(&kernel.kernel, detach, upstream_image));
        rec.dispatch_linear(kernel, batch.layout.tiles, bufs, &p)?;
        rec.work_of_next(counts.project_backward(accumulate));
        self.record_projection_backward(rec, gaussians, grads, count, n_views, accumulate)
    }

    /// `project_backward`: the splats' gradients through the projection to
    /// every Gaussian parameter.
    fn record_projection_backward<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        gaussians: &'a GaussianBuffers,
        grads: &'a GaussianBuffers,
        count: u64,
        n_views: u32,
        accumulate: bool,
    ) -> Result<()> {
        rec.dispatch_linear(
            &PROJECT_BACKWARD,
            count.div_ceil(256) as u32,
            bind::ProjectBackwardBuffers {
                views: self.views.get(),
                means: &gaussians.means,
                log_scales: &gaussians.log_scales,
                quats: &gaussians.quats,
                logits: &gaussians.opacity_logits,
                tile_counts: self.tile_counts.get(),
                grad_splats: self.grad_splats.get(),
                grad_means: &grads.means,
                grad_log_scales: &grads.log_scales,
                grad_quats: &grads.quats,
                grad_logits: &grads.opacity_logits,
            },
            &push::ProjectBackward {
                n_gaussians: count as u32,
                n_views,
                accumulate: accumulate as u32,
            },
        )
    }

    /// Records region pooling of the last forward batch's query channels
    /// without a per-pixel query image (kernel `shaders/wgsl/raster_pool.wgsl`):
    /// adds `query[p] / |r|` of every pixel p of region r into 32-float row
    /// `first_row + r` of `pooled`, so rows zero-filled before hold each
    /// region's mean rendered query. `labels` holds each batch pixel's
    /// region (`u32::MAX` for none) and, from index `offsets_at`, the
    /// regions' CSR offsets, as for [`QueryGradients::Regions`]. Any
    /// [`Channels`] of forward pass will do: only its blending state is
    /// read. `gaussians` must be unchanged since the forward pass, and
    /// `batch` is the batch rendered last (as for
    /// [`Rasterizer::record_backward_into`]).
    #[allow(clippy::too_many_arguments)]
    pub fn record_pool<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        batch: &RenderBatch,
        gaussians: &'a GaussianBuffers,
        pooled: &'a Buffer,
        first_row: u32,
        labels: &'a Buffer,
        offsets_at: u32,
    ) -> Result<()> {
        self.images()?;
        Self::check_region_labels(batch, labels, offsets_at)?;
        pooled.ensure_bytes(
            (first_row as u64 + 1) * QUERY_DIM as u64 * 4,
            "region pooling",
        )?;
        let p = push::RasterPool {
            n_gaussians: batch.count as u32,
            n_views: batch.layout.views.len() as u32,
            n_tiles: batch.layout.tiles,
            first_row,
            offsets_at,
        };
        let bufs = bind::RasterPoolBuffers {
            views: self.views.get(),
            queries: &gaussians.queries,
            splats: self.splats.get(),
            pairs: self.isect_pairs.get(),
            ranges: self.ranges.get(),
            state: self.state.get(),
            labels,
            pooled,
        };
        let kernel = buildable(rec, &self.settings, |s| pool_kernel(rec.info(), s))?;
        // The rows pooled into are not known here; their 4 bytes each are
        // a small term.
        rec.work_of_next(BatchCounts::of(batch).pool(&kernel.kernel, 0.0));
        rec.dispatch_linear(kernel, batch.layout.tiles, bufs, &p)?;
        Ok(())
    }

    /// [`Rasterizer::record_backward`], submitted and waited for.
    pub fn backward(&self, gaussians: &GaussianBuffers, grads: &GaussianBuffers) -> Result<()> {
        let mut rec = self.ctx.recorder()?;
        self.record_backward(&mut rec, gaussians, grads)?;
        rec.submit()?.wait()
    }
}
