//! Gaussian splatting on the GPU: parameter storage, cameras, and the
//! differentiable rasterizer (forward and backward).
//!
//! Where things are: kernels `glsl/project_forward.comp`,
//! `glsl/tile_bins.comp`, `glsl/raster_forward.comp`,
//! `shaders/wgsl/raster_backward.wgsl`, `glsl/project_backward.comp` (shared
//! GLSL in `glsl/splat.glsl`); the f64 CPU reference, which also states the
//! math, in `latentam_reference::raster`.

mod gaussians;
mod grid;
mod rasterizer;
mod views;

#[cfg(test)]
mod tests;

pub use gaussians::{GaussianBuffers, GaussianReadback, FIELD_WIDTHS, GAUSSIAN_BYTES};
pub use grid::PixelGrid;
pub use latentam_base::{Camera, HostGaussians, GUARD_BAND, QUERY_DIM};
pub use rasterizer::{
    BlendLayout, Channels, ColourRender, ForwardStats, PixelBuffers, QueryGradients, Rasterizer,
    RenderBatch, RenderSettings, RenderedView,
};
pub use views::{BatchLayout, ViewSlot};

/// Tiles are `TILE_SIZE` × `TILE_SIZE` pixels.
pub use latentam_shaders::shared::TILE_SIZE;
