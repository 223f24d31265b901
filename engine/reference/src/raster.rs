//! The Gaussian rasterizer's math in f64: projection, tile culling,
//! front-to-back blending, and the backward pass to every parameter.
//!
//! GPU kernels: `glsl/project_forward.comp`, `glsl/raster_forward.comp`,
//! `shaders/wgsl/raster_backward.wgsl`, `glsl/project_backward.comp`
//! (orchestrated by `latentam_core::splat::Rasterizer`).
//!
//! Conventions (see [`Camera`](latentam_base::Camera) for the pixel convention):
//! * a Gaussian has centre μ, scale s = exp(log_scale), rotation R(q̂) from
//!   the normalised quaternion q̂ = q/|q| (w, x, y, z), opacity
//!   o = sigmoid(logit), colour c and query f;
//! * its world covariance is Σ = M Mᵀ with M = R(q̂)·diag(s);
//! * in a camera with world-to-camera [W|w]: t = Wμ + w, Σc = W Σ Wᵀ,
//!   image mean m = (fx tx/tz + cx, fy ty/tz + cy) and 2-D covariance
//!   Σ₂ = J Σc Jᵀ + 0.3·I, J the projection's Jacobian at t with tx/tz, ty/tz
//!   clamped to the field of view widened by 30 % (a guard band that keeps
//!   Gaussians far off-screen from blowing up), and conic (a, b, c) = Σ₂⁻¹;
//! * per pixel p, front to back in depth (tz) order:
//!   σ = ½(a dx² + c dy²) + b dx dy with d = m − p, α = min(0.99, o e^(−σ));
//!   a Gaussian with σ < 0 or α < 1/255 is skipped; if T(1 − α) < 1e-4 the
//!   pixel stops before it; otherwise it adds w = αT of its colour, query and
//!   depth tz, and T ← T(1 − α);
//! * outputs: colour Σwc + T·background, depth Σw·tz (not normalised),
//!   alpha 1 − T, query Σwf (background 0).
//!
//! Only Gaussians whose tile rectangle covers a pixel's 16×16 tile are
//! considered for it: the rectangle is the Gaussian's opacity-aware 2-D box,
//! m ± ⌈ext·√Σ₂ᵢᵢ⌉ per axis with ext = min(3.33, √(2 ln(255·o))), outside
//! which α < 1/255 anyway.

// `!(x > 0.0)` is deliberate: NaN must take the culling branch. Index loops
// mirror the sums in the math.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

mod backward;
mod blend;
pub mod cutoffs;
mod gaussian;
mod projection;

pub use backward::{backward, GaussianGrads};
pub use blend::{blend_work, render, BlendWork};
pub use gaussian::{
    quat_to_rotmat, Gaussian, Image, ImageGrads, CHANNELS, LOW_PASS, MAX_ALPHA, MIN_ALPHA,
    MIN_TRANSMITTANCE,
};
pub use latentam_base::GUARD_BAND;
pub use projection::{project, Projected};
