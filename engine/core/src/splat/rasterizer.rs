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

use latentam_shaders::shared::TileRange;
use latentam_shaders::{
    push, KernelDef, PROJECT_BACKWARD, RASTER_BACKWARD, RASTER_BACKWARD_CAS,
    RASTER_BACKWARD_COLUMNS, RASTER_BACKWARD_COLUMNS_ATTACHED,
    RASTER_BACKWARD_COLUMNS_ATTACHED_CAS, RASTER_BACKWARD_COLUMNS_ATTACHED_PLAIN,
    RASTER_BACKWARD_COLUMNS_ATTACHED_PLAIN_CAS, RASTER_BACKWARD_COLUMNS_CAS,
    RASTER_BACKWARD_COLUMNS_PLAIN, RASTER_BACKWARD_COLUMNS_PLAIN_CAS, RASTER_BACKWARD_PLAIN,
    RASTER_BACKWARD_PLAIN_CAS, RASTER_FORWARD, RASTER_FORWARD_COLOUR, RASTER_FORWARD_COLUMNS,
    RASTER_FORWARD_COLUMNS_COLOUR, RASTER_POOL, RASTER_POOL_CAS, RASTER_POOL_COLUMNS,
    RASTER_POOL_COLUMNS_CAS, RASTER_POOL_PLAIN, RASTER_POOL_PLAIN_CAS,
};

mod backward;
use backward::{backward_kernel, pool_kernel};
mod forward;

pub use forward::RenderBatch;

use super::views::BatchLayout;
use super::{GaussianBuffers, QUERY_DIM};
use latentam_base::{Error, Result};
use latentam_gpu::ops::{PrefixScan, RadixSorter};
use latentam_gpu::{Buffer, Context, DeviceInfo, Recorder};

/// How the blending kernels map a tile's pixels to invocations. Both give
/// the same images and gradients (up to f32 summation order); they differ in
/// speed by device.
///
/// ```
/// use ash::vk::PhysicalDeviceType;
/// use latentam_core::splat::{BlendLayout, RenderSettings};
///
/// let auto = RenderSettings::default().layout;
/// assert_eq!(auto.resolve(PhysicalDeviceType::CPU), BlendLayout::Columns);
/// assert_eq!(auto.resolve(PhysicalDeviceType::DISCRETE_GPU), BlendLayout::Pixels);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BlendLayout {
    /// [`BlendLayout::Columns`] on CPU devices, [`BlendLayout::Pixels`] on
    /// GPUs.
    #[default]
    Auto,
    /// One pixel per invocation, the usual GPU layout.
    Pixels,
    /// One 16-pixel tile column per invocation: a Gaussian's data is loaded
    /// once for 16 pixels, which pays on CPU drivers (lavapipe), where
    /// loads are emulated lane by lane and branches do not skip work.
    Columns,
}

impl BlendLayout {
    /// The layout used on a device of type `device_type`.
    pub fn resolve(self, device_type: ash::vk::PhysicalDeviceType) -> Self {
        match self {
            Self::Auto if device_type == ash::vk::PhysicalDeviceType::CPU => Self::Columns,
            Self::Auto => Self::Pixels,
            other => other,
        }
    }
}

/// How views are rendered and differentiated.
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context) {
/// use latentam_core::splat::{Rasterizer, RenderSettings};
///
/// let mut raster = Rasterizer::new(ctx);
/// raster.settings = RenderSettings { background: [1.0; 3], ..Default::default() };
/// assert!(raster.settings.detach_query_gradients);
/// # }
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Colour behind the Gaussians (linear RGB).
    pub background: [f32; 3],
    /// When set (the default), gradients of the query channels reach only the
    /// Gaussians' queries, never their opacity or geometry, so the feature
    /// loss cannot reshape the map (the Feature-3DGS choice).
    pub detach_query_gradients: bool,
    /// Pixel-to-invocation mapping of the blending kernels.
    pub layout: BlendLayout,
    /// Whether [`Rasterizer::image_grads`] has a per-pixel query gradient
    /// image ([`QueryGradients::Image`]); off, the 128 bytes a pixel are
    /// not allocated and the query gradients come from pooled region rows
    /// ([`QueryGradients::Regions`]) or are zero.
    pub query_gradient_image: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            background: [0.0; 3],
            detach_query_gradients: true,
            layout: BlendLayout::Auto,
            query_gradient_image: true,
        }
    }
}

/// Where the backward pass takes the upstream gradient of each pixel's
/// rendered query.
///
/// ```no_run
/// # use latentam_core::splat::{GaussianBuffers, Rasterizer};
/// # fn f(ctx: &latentam_gpu::Context, raster: &Rasterizer, params: &GaussianBuffers, grads: &GaussianBuffers) -> latentam_core::Result<()> {
/// use latentam_core::splat::QueryGradients;
///
/// // Colour and depth losses only: the query channels get no upstream gradient.
/// let mut rec = ctx.recorder()?;
/// raster.record_backward_into(&mut rec, raster.last_batch(), params, grads, false, QueryGradients::Zero)?;
/// rec.submit()?.wait()?;
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug)]
pub enum QueryGradients<'a> {
    /// The per-pixel image `image_grads()?.query()` (requires
    /// [`RenderSettings::query_gradient_image`]).
    Image,
    /// Region pooling's adjoint, without a per-pixel image: pixel p's
    /// gradient is `rows[first_row + region(p)] / |region(p)|` (32 floats a
    /// row), 0 for pixels in no region.
    Regions {
        /// ∂L/∂(pooled query), one 32-float row per region.
        rows: &'a Buffer,
        /// Row of region 0.
        first_row: u32,
        /// u32s: every batch pixel's region (`u32::MAX` for none), then,
        /// from index `offsets_at`, the regions' CSR offsets (sizes by
        /// difference), as [`crate::latent::Regions`] builds them.
        labels: &'a Buffer,
        /// Index of the first offset in `labels` (at least the batch's
        /// pixel count).
        offsets_at: u32,
    },
    /// No feature loss: zero.
    Zero,
}

/// Bytes of one pixel's query channels.
const QUERY_BYTES: u64 = QUERY_DIM as u64 * 4;

/// Which images a forward pass writes.
///
/// ```no_run
/// # use latentam_core::splat::{Camera, GaussianBuffers, Rasterizer};
/// # fn f(raster: &mut Rasterizer, params: &GaussianBuffers, count: u64, cams: &[Camera]) -> latentam_core::Result<()> {
/// use latentam_core::splat::Channels;
///
/// // Seeding needs coverage and depth only: skip the 32 query channels.
/// raster.forward_channels(params, count, cams, Channels::Colour)?;
/// let (alpha, depth) = raster.download_alpha_depth(0)?;
/// assert_eq!(raster.channels(), Channels::Colour);
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Channels {
    /// Colour, depth, alpha and the 32 query channels.
    #[default]
    All,
    /// Colour, depth and alpha only: the query image keeps whatever it
    /// held. Blending skips the query channels (on lavapipe a forward pass
    /// then takes about 40 % of the time). The backward pass is exact when
    /// query gradients are detached
    /// ([`RenderSettings::detach_query_gradients`]), as it then reads no
    /// rendered query.
    Colour,
}

/// Per-pixel buffers of a batch (all views back to back, each row-major; see
/// [`BatchLayout`]). The forward pass writes them; the same layout carries
/// the upstream gradients into the backward pass.
///
/// ```no_run
/// # use latentam_core::splat::{Camera, GaussianBuffers, Rasterizer};
/// # fn f(ctx: &latentam_gpu::Context, raster: &mut Rasterizer, params: &GaussianBuffers, grads: &GaussianBuffers, cams: &[Camera]) -> latentam_core::Result<()> {
/// raster.forward(params, params.capacity(), cams)?;
/// let rgbd = ctx.download::<[f32; 4]>(&raster.images()?.rgbd)?;
/// // ∂L/∂(images) go into the same layout, then back to the Gaussians.
/// let mut rec = ctx.recorder()?;
/// raster.image_grads()?.record_fill(&mut rec, 0);
/// raster.record_backward(&mut rec, params, grads)?;
/// rec.submit()?.wait()?;
/// # Ok(())
/// # }
/// ```
pub struct PixelBuffers {
    /// 4 floats per pixel: R, G, B (background included), depth Σ w·z.
    pub rgbd: Buffer,
    /// 1 float per pixel: accumulated alpha.
    pub alpha: Buffer,
    /// [`QUERY_DIM`] floats per pixel: the blended query vector; allocated
    /// only where query channels are rendered (or their gradients taken
    /// per pixel).
    query: Option<Buffer>,
    name: &'static str,
    pixels: u64,
}

impl PixelBuffers {
    fn new(ctx: &Context, name: &'static str, pixels: u64) -> Result<Self> {
        let p = pixels.max(1);
        Ok(Self {
            rgbd: Buffer::device(ctx, &format!("pixels/{name}_rgbd"), p * 16)?,
            alpha: Buffer::device(ctx, &format!("pixels/{name}_alpha"), p * 4)?,
            query: None,
            name,
            pixels,
        })
    }

    /// Allocates the query image for `pixels` pixels (at most the whole
    /// batch).
    fn ensure_query(&mut self, ctx: &Context, pixels: u64) -> Result<()> {
        if self.query.is_none() {
            // A category of its own: the per-pixel feature memory.
            let name = format!("features/{}_query", self.name);
            let bytes = pixels.min(self.pixels).max(1) * QUERY_BYTES;
            self.query = Some(Buffer::device(ctx, &name, bytes)?);
        }
        Ok(())
    }

    /// How many pixels the buffers hold.
    pub fn pixels(&self) -> u64 {
        self.pixels
    }

    /// [`QUERY_DIM`] floats per pixel: the blended query vector (or its
    /// gradient); an error where none is allocated. A batch whose query
    /// image does not fit one buffer of the device is rendered in bands:
    /// this buffer then holds only the last band, and
    /// [`Rasterizer::download_view`] returns the whole view.
    pub fn query(&self) -> Result<&Buffer> {
        self.query.as_ref().ok_or_else(|| {
            Error::InvalidArgument(
                "no per-pixel query image: render with Channels::All (images) or keep \
                 RenderSettings::query_gradient_image (gradients)"
                    .into(),
            )
        })
    }

    /// Records a fill of every allocated buffer with a bit pattern.
    pub fn record_fill<'a>(&'a self, rec: &mut Recorder<'a>, bits: u32) {
        rec.fill_u32(&self.rgbd, bits);
        rec.fill_u32(&self.alpha, bits);
        if let Some(q) = &self.query {
            rec.fill_u32(q, bits);
        }
    }
}

/// One view's images on the host.
///
/// ```no_run
/// # fn f(raster: &latentam_core::splat::Rasterizer) -> latentam_core::Result<()> {
/// let view = raster.download_view(0)?;
/// let centre = (view.height / 2 * view.width + view.width / 2) as usize;
/// let [r, g, b, weighted_depth] = view.rgbd[centre];
/// let depth = weighted_depth / view.alpha[centre].max(1e-6);
/// let query: &[f32; 32] = &view.query[centre];
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct RenderedView {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Per pixel, row-major: R, G, B, depth.
    pub rgbd: Vec<[f32; 4]>,
    /// Per pixel: accumulated alpha.
    pub alpha: Vec<f32>,
    /// Per pixel: the query vector.
    pub query: Vec<[f32; QUERY_DIM]>,
}

/// Counts from the last forward pass.
///
/// ```no_run
/// # use latentam_core::splat::{Camera, GaussianBuffers, Rasterizer};
/// # fn f(raster: &mut Rasterizer, params: &GaussianBuffers, count: u64, cams: &[Camera]) -> latentam_core::Result<()> {
/// let stats = raster.forward(params, count, cams)?;
/// let per_pair = stats.intersections as f64 / stats.visible.max(1) as f64;
/// println!("{} visible pairs, {per_pair:.1} tiles each", stats.visible);
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct ForwardStats {
    /// (view, Gaussian) pairs that survived culling.
    pub visible: u64,
    /// (tile, Gaussian) intersections blended.
    pub intersections: u64,
}

// Which variant of each blending kernel a device runs: one table for the
// dispatches and for `Rasterizer::blend_kernel_names`.

fn forward_kernel(
    info: &DeviceInfo,
    settings: &RenderSettings,
    channels: Channels,
) -> &'static KernelDef<push::RasterForward> {
    let columns = settings.layout.resolve(info.device_type) == BlendLayout::Columns;
    match (columns, channels) {
        (true, Channels::All) => &RASTER_FORWARD_COLUMNS,
        (true, Channels::Colour) => &RASTER_FORWARD_COLUMNS_COLOUR,
        (false, Channels::All) => &RASTER_FORWARD,
        (false, Channels::Colour) => &RASTER_FORWARD_COLOUR,
    }
}

/// A buffer that grows (by 25 % headroom) when a batch needs more.
struct Grow {
    name: &'static str,
    buf: Option<Buffer>,
}

impl Grow {
    const fn new(name: &'static str) -> Self {
        Self { name, buf: None }
    }

    fn ensure(&mut self, ctx: &Context, bytes: u64) -> Result<()> {
        let bytes = bytes.max(4);
        if self.buf.as_ref().is_some_and(|b| b.bytes() >= bytes) {
            return Ok(());
        }
        let limit = ctx.info().max_storage_buffer_range;
        if bytes > limit {
            return Err(Error::Unsupported(format!(
                "`{}` needs {bytes} bytes, over the device's largest storage buffer ({limit}); \
                 render fewer views or Gaussians per batch",
                self.name
            )));
        }
        self.buf = None;
        let padded = (bytes + bytes / 4).min(limit).div_ceil(4) * 4;
        self.buf = Some(Buffer::device(ctx, self.name, padded)?);
        Ok(())
    }

    fn get(&self) -> &Buffer {
        self.buf
            .as_ref()
            .expect("buffer sized by `ensure` before recording")
    }
}

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
            return Err(Error::InvalidArgument(format!(
                "region offsets at {offsets_at} overlap the labels of {} pixels",
                batch.layout.pixels
            )));
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
        let bufs = [
            self.views.get(),
            &gaussians.colors,
            &gaussians.queries,
            self.splats.get(),
            self.isect_pairs.get(),
            self.ranges.get(),
            &images.rgbd,
            &images.alpha,
            images.query.as_ref().unwrap_or(self.stub()?),
            self.state.get(),
        ];
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
        let kernel = forward_kernel(rec.info(), &self.settings, batch.channels);
        rec.dispatch_linear(kernel, layout.tiles, &bufs, &p)
    }

    /// Names of the blending kernels a rasterizer with `settings` dispatches
    /// on `info`'s device (forward with and without query channels,
    /// backward, pooling): the only `raster_*` kernels worth compiling
    /// ahead of time there (see [`crate::mapper::warm_up`]).
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
            return Err(Error::InvalidArgument(
                "the last forward pass rendered no query channels".into(),
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
            Error::InvalidArgument(format!(
                "view {index} of a batch of {}",
                self.last.layout.views.len()
            ))
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
    Error::InvalidArgument("the rasterizer has not rendered a batch yet".into())
}
