//! A batch of views measured for rendering, and the counts that size it.

use super::super::views::BatchLayout;
use super::Channels;
use latentam_shaders::shared::View;

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

/// One camera's colour, depth and alpha at a grid of its pixels, rendered
/// and read back in one submission by
/// [`Rasterizer::render_alpha_rgbd`](super::Rasterizer::render_alpha_rgbd).
#[derive(Clone, Debug, PartialEq)]
pub struct ColourRender {
    /// Accumulated alpha per cell of `grid`.
    pub alpha: Vec<f32>,
    /// Colour and unnormalised depth (Σ wᵢzᵢ) per cell.
    pub rgbd: Vec<[f32; 4]>,
    /// The pixels rendered and read back (every pixel with
    /// [`PixelGrid::ALL`](crate::splat::PixelGrid::ALL)).
    pub grid: crate::splat::PixelGrid,
    /// The other buffer asked for, read back after everything queued
    /// before the render, as `f32` words.
    pub also: Option<Vec<f32>>,
}

/// A batch of views, measured for rendering: its layout, the Gaussians it
/// renders and the counts that size the pass. [`Rasterizer::measure`](super::Rasterizer::measure)
/// makes them; [`Rasterizer::record_forward`](super::Rasterizer::record_forward), `record_pool` and
/// `record_backward_into` take them.
///
/// A measured batch stays valid while the Gaussians it was measured on are
/// unchanged: the counts are those of this exact projection.
///
/// ```no_run
/// # use latentam_core::splat::{Camera, GaussianBuffers, Rasterizer};
/// # fn f(ctx: &latentam_gpu::Context, raster: &mut Rasterizer, params: &GaussianBuffers, count: u64, near: &[Camera], far: &[Camera]) -> latentam_core::Result<()> {
/// use latentam_core::splat::Channels;
///
/// // One host wait measures both batches; each is then recorded without one.
/// let batches = raster.measure(params, count, &[near, far], Channels::All)?;
/// for batch in &batches {
///     let mut rec = ctx.recorder()?;
///     raster.record_forward(&mut rec, params, batch)?;
///     rec.submit()?.wait()?;
///     println!("{} tile intersections", batch.stats().intersections);
/// }
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Debug, Default)]
pub struct RenderBatch {
    pub(super) layout: BatchLayout,
    pub(super) views: Vec<View>,
    pub(super) count: u64,
    pub(super) channels: Channels,
    pub(super) stats: ForwardStats,
}

impl RenderBatch {
    /// Where each view's pixels and tiles sit.
    pub fn layout(&self) -> &BatchLayout {
        &self.layout
    }

    /// Visible pairs and tile intersections.
    pub fn stats(&self) -> ForwardStats {
        self.stats
    }

    /// Which images the forward pass writes.
    pub fn channels(&self) -> Channels {
        self.channels
    }

    /// Gaussians `0..gaussians()` are rendered.
    pub fn gaussians(&self) -> u64 {
        self.count
    }

    pub(super) fn pairs(&self) -> u64 {
        self.count * self.views.len() as u64
    }
}
