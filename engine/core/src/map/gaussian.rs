//! One Gaussian's parameters, as the global map stores them.

use crate::splat::QUERY_DIM;

/// One Gaussian's parameters, as the optimiser sees them (see
/// [`crate::splat::HostGaussians`] for the conventions).
///
/// ```
/// use bytemuck::Zeroable;
/// use latentam_core::map::Gaussian;
///
/// // A 1 cm, 90 % opaque red Gaussian 1 m in front of the origin.
/// let g = Gaussian {
///     mean: [0.0, 0.0, 1.0],
///     log_scale: [0.01f32.ln(); 3],
///     quat: [1.0, 0.0, 0.0, 0.0],
///     color: [1.0, 0.0, 0.0],
///     opacity_logit: (0.9f32 / 0.1).ln(),
///     ..Gaussian::zeroed() // query: all zero
/// };
/// let opacity = 1.0 / (1.0 + (-g.opacity_logit).exp());
/// assert!((opacity - 0.9).abs() < 1e-6);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Gaussian {
    /// Centre, world frame, metres.
    pub mean: [f32; 3],
    /// Log of the per-axis standard deviations.
    pub log_scale: [f32; 3],
    /// Rotation quaternion `(w, x, y, z)`.
    pub quat: [f32; 4],
    /// Linear RGB.
    pub color: [f32; 3],
    /// Opacity logit.
    pub opacity_logit: f32,
    /// Latent query.
    pub query: [f32; QUERY_DIM],
}
