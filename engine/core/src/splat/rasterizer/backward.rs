//! The backward pass (`raster_backward` per pixel, replaying the forward
//! walk, then `project_backward` per Gaussian) and region pooling of the
//! rendered queries (`raster_pool`), which walks the same tile lists.

use super::*;

pub(super) fn backward_kernel(
    info: &DeviceInfo,
    settings: &RenderSettings,
) -> &'static KernelDef<push::RasterBackward> {
    let columns = settings.layout.resolve(info.device_type) == BlendLayout::Columns;
    let attached = !settings.detach_query_gradients;
    // The column kernels sum a tile's 8 invocations with a shuffle
    // butterfly, which needs them to be exactly one subgroup.
    let sub = if columns {
        info.subgroup_shuffle && info.subgroup_size == 8
    } else {
        info.subgroup_arithmetic
    };
    match (columns, attached, sub, info.native_float_atomics) {
        (false, _, true, true) => &RASTER_BACKWARD,
        (false, _, true, false) => &RASTER_BACKWARD_CAS,
        (false, _, false, true) => &RASTER_BACKWARD_PLAIN,
        (false, _, false, false) => &RASTER_BACKWARD_PLAIN_CAS,
        (true, false, true, true) => &RASTER_BACKWARD_COLUMNS,
        (true, false, true, false) => &RASTER_BACKWARD_COLUMNS_CAS,
        (true, false, false, true) => &RASTER_BACKWARD_COLUMNS_PLAIN,
        (true, false, false, false) => &RASTER_BACKWARD_COLUMNS_PLAIN_CAS,
        (true, true, true, true) => &RASTER_BACKWARD_COLUMNS_ATTACHED,
        (true, true, true, false) => &RASTER_BACKWARD_COLUMNS_ATTACHED_CAS,
        (true, true, false, true) => &RASTER_BACKWARD_COLUMNS_ATTACHED_PLAIN,
        (true, true, false, false) => &RASTER_BACKWARD_COLUMNS_ATTACHED_PLAIN_CAS,
    }
}

pub(super) fn pool_kernel(
    info: &DeviceInfo,
    settings: &RenderSettings,
) -> &'static KernelDef<push::RasterPool> {
    let columns = settings.layout.resolve(info.device_type) == BlendLayout::Columns;
    match (columns, info.subgroup_arithmetic, info.native_float_atomics) {
        (true, _, true) => &RASTER_POOL_COLUMNS,
        (true, _, false) => &RASTER_POOL_COLUMNS_CAS,
        (false, true, true) => &RASTER_POOL,
        (false, true, false) => &RASTER_POOL_CAS,
        (false, false, true) => &RASTER_POOL_PLAIN,
        (false, false, false) => &RASTER_POOL_PLAIN_CAS,
    }
}

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
            return Err(Error::InvalidArgument(
                "query gradients reaching geometry need the rendered query: render with \
                 Channels::All"
                    .into(),
            ));
        }
        let (source, first_row, grad_query, labels, offsets_at) = match query {
            QueryGradients::Image => (0u32, 0u32, upstream.query()?, stub, 0u32),
            QueryGradients::Regions {
                rows,
                first_row,
                labels,
                offsets_at,
            } => {
                Self::check_region_labels(batch, labels, offsets_at)?;
                (1, first_row, rows, labels, offsets_at)
            }
            QueryGradients::Zero => (2, 0, stub, stub, 0),
        };
        let count = batch.count;
        if grads.capacity() < count || gaussians.capacity() < count {
            return Err(Error::InvalidArgument(format!(
                "backward over {count} Gaussians into buffers of capacity {}",
                grads.capacity().min(gaussians.capacity())
            )));
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
        let bufs = [
            self.views.get(),
            &gaussians.colors,
            &gaussians.queries,
            self.splats.get(),
            self.isect_pairs.get(),
            self.ranges.get(),
            &images.rgbd,
            images.query.as_ref().unwrap_or(stub),
            self.state.get(),
            &upstream.rgbd,
            &upstream.alpha,
            grad_query,
            &grads.colors,
            &grads.queries,
            self.grad_splats.get(),
            labels,
        ];
        let kernel = backward_kernel(rec.info(), &self.settings);
        rec.dispatch_linear(kernel, batch.layout.tiles, &bufs, &p)?;
        rec.dispatch_linear(
            &PROJECT_BACKWARD,
            count.div_ceil(256) as u32,
            &[
                self.views.get(),
                &gaussians.means,
                &gaussians.log_scales,
                &gaussians.quats,
                &gaussians.opacity_logits,
                self.tile_counts.get(),
                self.grad_splats.get(),
                &grads.means,
                &grads.log_scales,
                &grads.quats,
                &grads.opacity_logits,
            ],
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
        let bufs = [
            self.views.get(),
            &gaussians.queries,
            self.splats.get(),
            self.isect_pairs.get(),
            self.ranges.get(),
            self.state.get(),
            labels,
            pooled,
        ];
        let kernel = pool_kernel(rec.info(), &self.settings);
        rec.dispatch_linear(kernel, batch.layout.tiles, &bufs, &p)?;
        Ok(())
    }

    /// [`Rasterizer::record_backward`], submitted and waited for.
    pub fn backward(&self, gaussians: &GaussianBuffers, grads: &GaussianBuffers) -> Result<()> {
        let mut rec = self.ctx.recorder()?;
        self.record_backward(&mut rec, gaussians, grads)?;
        rec.submit()?.wait()
    }
}
