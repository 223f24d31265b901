//! How the rasterizer renders: the blending layout, the images written,
//! and where query gradients come from.

use latentam_gpu::Buffer;

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
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
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

impl latentam_base::settings::Setting for BlendLayout {}

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
    /// Whether [`Rasterizer::image_grads`](super::Rasterizer::image_grads) has a per-pixel query gradient
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
