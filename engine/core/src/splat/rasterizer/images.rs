//! The per-pixel images a batch renders into, and one rendered view read
//! back to the host.

use super::super::QUERY_DIM;
use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context, Recorder};

/// Bytes of one pixel's query channels.
pub(super) const QUERY_BYTES: u64 = QUERY_DIM as u64 * 4;

/// Per-pixel buffers of a batch (all views back to back, each row-major; see
/// [`BatchLayout`](crate::splat::BatchLayout)). The forward pass writes them; the same layout carries
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
    pub(super) query: Option<Buffer>,
    pub(super) name: &'static str,
    pub(super) pixels: u64,
}

impl PixelBuffers {
    pub(super) fn new(ctx: &Context, name: &'static str, pixels: u64) -> Result<Self> {
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
    pub(super) fn ensure_query(&mut self, ctx: &Context, pixels: u64) -> Result<()> {
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
    /// [`Rasterizer::download_view`](super::Rasterizer::download_view) returns the whole view.
    pub fn query(&self) -> Result<&Buffer> {
        self.query.as_ref().ok_or_else(|| {
            Error::bad_input(
                "query image",
                "no per-pixel query image: render with Channels::All (images) or keep \
                 RenderSettings::query_gradient_image (gradients)",
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
