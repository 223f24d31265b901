//! The differentiable rasterizer: forward rendering of a batch of views and
//! the backward pass to every Gaussian parameter.
//!
//! Forward, per batch:
//! 1. `project_forward`: every (view, Gaussian) pair → image-space splat, tile
//!    rectangle, tile count; the visible count and intersection total are
//!    read back (one short wait) to size what follows;
//! 2. `compact_visible` + radix sort by depth → visible pairs front to back;
//! 3. `gather_counts` + scan + `emit_tiles` → one (tile, pair) entry per
//!    covered tile, in depth order; a stable radix sort by tile id then
//!    leaves each tile's list sorted front to back; `tile_ranges` finds it;
//! 4. `raster_forward`: per-pixel blending.
//!
//! Backward: `raster_backward` (per pixel, replaying the forward walk) then
//! `project_backward` (per Gaussian, through the projection).
//!
//! The math, conventions and constants are stated once, in
//! `latentam_reference::raster`, the f64 CPU reference the tests compare
//! against.

mod backward;
mod batch;
mod forward;
mod grow;
mod images;
mod settings;
mod variants;
mod work;

pub use batch::{ColourRender, ForwardStats, RenderBatch};
use grow::Grow;
use images::QUERY_BYTES;
pub use images::{PixelBuffers, RenderedView};
pub use settings::{BlendLayout, Channels, QueryGradients, RenderSettings};
use variants::{backward_kernel, buildable, forward_kernel, pool_kernel};

use latentam_shaders::shared::TileRange;
use latentam_shaders::{bind, push, PROJECT_BACKWARD};

use super::views::BatchLayout;
use super::{GaussianBuffers, QUERY_DIM};
use latentam_base::{Error, Result};
use latentam_gpu::ops::{PrefixScan, RadixSorter};
use latentam_gpu::{Buffer, Context, DeviceInfo, Recorder};

/// Renders batches of views of a set of Gaussians and back-propagates
/// image-space gradients to them.
///
/// ```
/// use latentam_gpu::Context;
/// use latentam_core::splat::{Camera, GaussianBuffers, HostGaussians, Rasterizer};
/// let ctx = Context::new(Default::default())?;
/// let mut g = HostGaussians::zeros(1);
/// g.quats[0] = [1.0, 0.0, 0.0, 0.0];
/// g.log_scales[0] = [-2.0; 3];
/// g.colors[0] = [1.0, 0.5, 0.0];
/// g.opacity_logits[0] = 2.0;
/// let gpu = GaussianBuffers::new(&ctx, "example", 1)?;
/// gpu.upload(&ctx, 0, &g)?;
/// let cam = Camera::looking_at(
///     glam::DVec3::new(0.0, 0.0, -2.0), glam::DVec3::ZERO, glam::DVec3::NEG_Y, 32, 24, 40.0);
/// let mut raster = Rasterizer::new(&ctx);
/// let stats = raster.forward(&gpu, 1, &[cam])?;
/// assert_eq!(stats.visible, 1);
/// let img = raster.download_view(0)?;
/// let centre = img.rgbd[(12 * 32 + 16) as usize];
/// assert!(centre[0] > 0.5 && (centre[3] - 2.0 * img.alpha[12 * 32 + 16]).abs() < 1e-3);
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct Rasterizer {
    ctx: Context,
    /// Background and gradient routing; read by every forward/backward.
    pub settings: RenderSettings,
    /// The last batch [`Rasterizer::forward_channels`] rendered.
    last: RenderBatch,
    views: Grow,
    splats: Grow,
    rects: Grow,
    tile_counts: Grow,
    positions: Grow,
    pair_offsets: Grow,
    depth_keys: Grow,
    depth_order: Grow,
    sorted_offsets: Grow,
    isect_keys: Grow,
    isect_pairs: Grow,
    ranges: Grow,
    state: Grow,
    grad_splats: Grow,
    /// A render's values at a grid of pixels, gathered for read-back
    /// ([`Rasterizer::render_alpha_rgbd`]).
    grid_cells: Grow,
    images: Option<PixelBuffers>,
    image_grads: Option<PixelBuffers>,
    /// The last batch's query image, when it was rendered in bands (too
    /// large for one buffer).
    banded_query: Option<Vec<f32>>,
    /// Bound in place of a buffer a kernel variant declares but the pass
    /// does not read (allocated by the first forward pass).
    stub: Option<Buffer>,
    scan: Option<PrefixScan>,
    sorter: Option<RadixSorter>,
}

impl Rasterizer {
    /// A rasterizer with default [`RenderSettings`]; buffers are allocated by
    /// the first forward pass and grown as batches need.
    pub fn new(ctx: &Context) -> Self {
        Self {
            ctx: ctx.clone(),
            settings: RenderSettings::default(),
            last: RenderBatch::default(),
            views: Grow::new("raster/views"),
            splats: Grow::new("raster/splats"),
            rects: Grow::new("raster/rects"),
            tile_counts: Grow::new("raster/tile_counts"),
            positions: Grow::new("raster/positions"),
            pair_offsets: Grow::new("raster/pair_offsets"),
            depth_keys: Grow::new("raster/depth_keys"),
            depth_order: Grow::new("raster/depth_order"),
            sorted_offsets: Grow::new("raster/sorted_offsets"),
            isect_keys: Grow::new("raster/isect_keys"),
            isect_pairs: Grow::new("raster/isect_pairs"),
            ranges: Grow::new("raster/ranges"),
            state: Grow::new("pixels/blend_state"),
            grad_splats: Grow::new("raster/grad_splats"),
            grid_cells: Grow::new("raster/grid_cells"),
            images: None,
            image_grads: None,
            banded_query: None,
            stub: None,
            scan: None,
            sorter: None,
        }
    }

    /// Layout of the last forward batch.
    pub fn layout(&self) -> &BatchLayout {
        &self.last.layout
    }

    /// Counts of the last forward batch.
    pub fn stats(&self) -> ForwardStats {
        self.last.stats
    }

    /// The last batch [`Rasterizer::forward_channels`] rendered, for the
    /// `record_*` calls that take one.
    pub fn last_batch(&self) -> &RenderBatch {
        &self.last
    }

    /// The last forward pass's images.
    pub fn images(&self) -> Result<&PixelBuffers> {
        self.images.as_ref().ok_or_else(no_forward)
    }

    /// Buffers for ∂L/∂(images) of the last batch, laid out like
    /// [`Rasterizer::images`]; fill them before the backward pass. Their
    /// contents are undefined after a forward pass.
    pub fn image_grads(&self) -> Result<&PixelBuffers> {
        self.image_grads.as_ref().ok_or_else(no_forward)
    }

    fn ensure_scan(&mut self, len: u64) -> Result<()> {
        if self.scan.as_ref().is_none_or(|s| s.max_len() < len) {
            self.scan = None;
            self.scan = Some(PrefixScan::new(&self.ctx, len + len / 4)?);
        }
        Ok(())
    }

    fn ensure_sorter(&mut self, len: u64) -> Result<()> {
        if self.sorter.as_ref().is_none_or(|s| s.max_len() < len) {
            self.sorter = None;
            self.sorter = Some(RadixSorter::new(&self.ctx, len + len / 4)?);
        }
        Ok(())
    }

    fn ensure_pixels(&mut self, pixels: u64, channels: Channels) -> Result<()> {
        if self.images.as_ref().is_none_or(|b| b.pixels < pixels) {
            self.images = None;
            self.image_grads = None;
            self.images = Some(PixelBuffers::new(&self.ctx, "images", pixels)?);
            self.image_grads = Some(PixelBuffers::new(&self.ctx, "image_grads", pixels)?);
        }
        let ctx = self.ctx.clone();
        if channels == Channels::All {
            // Banded when the batch's would not fit one buffer.
            let band = self.query_band_pixels();
            self.images
                .as_mut()
                .expect("sized")
                .ensure_query(&ctx, band)?;
        }
        if self.settings.query_gradient_image {
            // Per-pixel gradients are read whole by the backward pass.
            self.image_grads
                .as_mut()
                .expect("sized")
                .ensure_query(&ctx, pixels)?;
        }
        if self.stub.is_none() {
            self.stub = Some(Buffer::device(&ctx, "raster/stub", 256)?);
        }
        Ok(())
    }

    fn stub(&self) -> Result<&Buffer> {
        self.stub.as_ref().ok_or_else(no_forward)
    }

    /// Checks a labels buffer (each batch pixel's region, then from
    /// `offsets_at` the regions' CSR offsets) against `batch`.
    fn check_region_labels(batch: &RenderBatch, labels: &Buffer, offsets_at: u32) -> Result<()> {
        if (offsets_at as u64) < batch.layout.pixels {
            return Err(Error::bad_input(
                "region labels and offsets",
                format!(
                    "offsets at {offsets_at} overlap the labels of {} pixels",
                    batch.layout.pixels
                ),
            ));
        }
        labels.ensure_bytes((offsets_at as u64 + 1) * 4, "region labels and offsets")
    }

    /// Pixels of query image one buffer holds on this device.
    fn query_band_pixels(&self) -> u64 {
        (self.ctx.info().max_buffer_bytes() / QUERY_BYTES).max(1)
    }

    /// Records the blending kernel of the binned `batch`, writing the
    /// query channels (with [`Channels::All`]) of batch pixels
    /// `query_first..query_first + query_count` to the query image.
    fn record_blend<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        gaussians: &'a GaussianBuffers,
        batch: &RenderBatch,
        query_first: u64,
        query_count: u64,
    ) -> Result<()> {
        let images = self.images()?;
        let bg = self.settings.background;
        let bufs = bind::RasterForwardBuffers {
            views: self.views.get(),
            colors: &gaussians.colors,
            queries: &gaussians.queries,
            splats: self.splats.get(),
            pairs: self.isect_pairs.get(),
            ranges: self.ranges.get(),
            rgbd: &images.rgbd,
            alpha: &images.alpha,
            query: images.query.as_ref().unwrap_or(self.stub()?),
            state: self.state.get(),
        };
        let layout = &batch.layout;
        let p = push::RasterForward {
            n_gaussians: batch.count as u32,
            n_views: layout.views.len() as u32,
            n_tiles: layout.tiles,
            bg_r: bg[0],
            bg_g: bg[1],
            bg_b: bg[2],
            query_first: query_first as u32,
            query_count: query_count as u32,
        };
        let kernel = buildable(rec, &self.settings, |s| {
            forward_kernel(rec.info(), s, batch.channels)
        })?;
        rec.work_of_next(
            work::BatchCounts::of(batch).blend_forward(&kernel.kernel, query_count as f64),
        );
        rec.dispatch_linear(kernel, layout.tiles, bufs, &p)
    }

    /// Names of the blending kernels a rasterizer with `settings` dispatches
    /// on `info`'s device (forward with and without query channels,
    /// backward, pooling): the only `raster_*` kernels worth compiling
    /// ahead of time there (see [`crate::mapper::Mapper::warm_up`]).
    pub fn blend_kernel_names(info: &DeviceInfo, settings: &RenderSettings) -> [&'static str; 4] {
        [
            forward_kernel(info, settings, Channels::All).kernel.name,
            forward_kernel(info, settings, Channels::Colour).kernel.name,
            backward_kernel(info, settings).kernel.name,
            pool_kernel(info, settings).kernel.name,
        ]
    }

    /// Length of every tile's Gaussian list in the last forward batch, in
    /// batch tile order (see [`BatchLayout`]); a diagnostic of the load.
    pub fn tile_list_lengths(&self) -> Result<Vec<u32>> {
        let tiles = self.last.layout.tiles as u64;
        if tiles == 0 {
            return Err(no_forward());
        }
        let mut rec = self.ctx.recorder()?;
        let bytes = tiles * std::mem::size_of::<TileRange>() as u64;
        let rb = rec.download(self.ranges.get(), 0, bytes)?;
        rec.submit()?.wait()?;
        Ok(rb
            .read::<TileRange>()?
            .iter()
            .map(|r| r.end.saturating_sub(r.start))
            .collect())
    }

    /// Which images the last forward pass wrote.
    pub fn channels(&self) -> Channels {
        self.last.channels
    }

    /// Downloads view `index` of the last forward batch (an error after a
    /// [`Channels::Colour`] pass, whose query image is stale).
    pub fn download_view(&self, index: usize) -> Result<RenderedView> {
        if self.last.channels != Channels::All {
            return Err(Error::bad_input(
                "the rendered view",
                "the last forward pass rendered no query channels",
            ));
        }
        let slot = self.view_slot(index)?;
        let images = self.images()?;
        let n = slot.width as u64 * slot.height as u64;
        let first = slot.first_pixel;
        let mut rec = self.ctx.recorder()?;
        let rgbd = rec.download(&images.rgbd, first * 16, n * 16)?;
        let alpha = rec.download(&images.alpha, first * 4, n * 4)?;
        let query = match &self.banded_query {
            None => Some(rec.download(images.query()?, first * QUERY_BYTES, n * QUERY_BYTES)?),
            Some(_) => None,
        };
        rec.submit()?.wait()?;
        let query = match query {
            Some(rb) => rb.read::<f32>()?,
            None => {
                let host = self.banded_query.as_ref().ok_or_else(no_forward)?;
                let q = QUERY_DIM;
                host[first as usize * q..(first + n) as usize * q].to_vec()
            }
        };
        Ok(RenderedView {
            width: slot.width,
            height: slot.height,
            rgbd: bytemuck::cast_slice(&rgbd.read::<f32>()?).to_vec(),
            alpha: alpha.read::<f32>()?,
            query: bytemuck::cast_slice(&query).to_vec(),
        })
    }
}

impl Rasterizer {
    fn view_slot(&self, index: usize) -> Result<super::ViewSlot> {
        self.last.layout.views.get(index).copied().ok_or_else(|| {
            Error::bad_input(
                format!("view {index}"),
                format!(
                    "not in the last batch, of {} views",
                    self.last.layout.views.len()
                ),
            )
        })
    }

    /// Accumulated alpha and unnormalised depth (Σ wᵢzᵢ) of view `index`
    /// of the last forward batch: what seeding needs, without the 32 query
    /// channels [`Rasterizer::download_view`] also fetches.
    pub fn download_alpha_depth(&self, index: usize) -> Result<(Vec<f32>, Vec<f32>)> {
        let (alpha, rgbd) = self.download_alpha_rgbd(index)?;
        Ok((alpha, rgbd.iter().map(|p| p[3]).collect()))
    }

    /// Accumulated alpha and the colour-and-depth image (unnormalised:
    /// Σ wᵢcᵢ, Σ wᵢzᵢ) of view `index` of the last forward batch.
    pub fn download_alpha_rgbd(&self, index: usize) -> Result<(Vec<f32>, Vec<[f32; 4]>)> {
        let slot = self.view_slot(index)?;
        let images = self.images()?;
        let n = slot.width as u64 * slot.height as u64;
        let first = slot.first_pixel;
        let mut rec = self.ctx.recorder()?;
        let rgbd = rec.download(&images.rgbd, first * 16, n * 16)?;
        let alpha = rec.download(&images.alpha, first * 4, n * 4)?;
        rec.submit()?.wait()?;
        Ok((
            alpha.read::<f32>()?,
            bytemuck::cast_slice(&rgbd.read::<f32>()?).to_vec(),
        ))
    }
}

fn no_forward() -> Error {
    Error::bad_input("rasterizer", "it has not rendered a batch yet")
}
