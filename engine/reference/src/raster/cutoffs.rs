//! Where f32 and f64 blending may rightly disagree.
//!
//! Blending has three discrete decisions: a Gaussian is skipped when its
//! alpha is below 1/255, a pixel stops when its transmittance would fall
//! below 1e-4, and overlapping Gaussians blend in depth order. Alpha is also
//! clamped at 0.99, which switches its gradient off. When a value sits
//! within rounding of one of these thresholds, an f32 kernel and the f64
//! reference can both be right and still decide differently, and the pixel
//! (and the gradients of every Gaussian blended into it) jump by a finite
//! amount. Tests compare everything else tightly and use this to know which
//! pixels and Gaussians to leave out, instead of loosening every tolerance.

use super::blend::{covers_tile, falloff, sorted_visible};
use super::gaussian::{Gaussian, MAX_ALPHA, MIN_ALPHA, MIN_TRANSMITTANCE};
use latentam_base::Camera;
use latentam_shaders::shared::TILE_SIZE;

/// Pixels and Gaussians of one view at a blending threshold.
///
/// ```
/// use latentam_reference::raster::{cutoffs::near_cutoffs, Gaussian};
/// use latentam_base::Camera;
///
/// let cam = Camera::at_origin(32, 24);
/// let g = Gaussian { mean: [0.0, 0.0, 2.0], log_scale: [-2.0; 3], quat: [1.0, 0.0, 0.0, 0.0],
///     color: [1.0, 0.0, 0.0], opacity_logit: 2.0, query: [0.0; 32] };
/// let cut = near_cutoffs(&[g], &cam);
/// assert_eq!((cut.slack.len(), cut.gaussians.len()), (cam.pixels() as usize, 1));
/// // A GPU test compares tightly only the pixels with no slack.
/// let compared = cut.slack.iter().filter(|&&s| s == 0.0).count();
/// assert!(compared > 0);
/// ```
#[derive(Clone, Debug)]
pub struct NearCutoffs {
    /// Per pixel (row-major): the blending weight that may legitimately
    /// differ. A channel may be off by up to this times twice the largest
    /// |feature| blended (1 for colour and query, the largest depth for
    /// depth); alpha by up to this.
    pub slack: Vec<f64>,
    /// Per Gaussian (input order): its own decision is at a threshold at
    /// some pixel, so its gradient may jump by a finite amount.
    pub gaussians: Vec<bool>,
}

/// Relative margin on alpha and transmittance. They come from e^(−σ), σ up
/// to ~5.5 at the 1/255 cut-off, computed in f32 from a conic that carries
/// cancellation error: kernels land within ~3e-6 of the f64 value.
pub const ALPHA_MARGIN: f64 = 2e-5;
/// Relative margin on depth: camera-frame depth is one f32 affine map of
/// the centre, good to a few ulp (~3e-7).
pub const DEPTH_MARGIN: f64 = 1e-6;

/// Finds, for one view, the blending decisions within rounding of their
/// thresholds: alpha against 1/255 and 0.99 and transmittance against 1e-4
/// within `ALPHA_MARGIN`, consecutive contributors' depths within
/// `DEPTH_MARGIN` of each other. Each adds to its pixel's slack the weight
/// it can move: 2αT for a Gaussian at the alpha cut-off (its own weight,
/// and the share it takes from those behind), αT + 2e-4 at the
/// transmittance cut-off, α₁α₂T for two Gaussians that may swap; the clamp
/// at 0.99 moves no value. The Gaussians flagged are the ones whose own
/// decision it is (both, for a tie): their gradients may jump. Gaussians in
/// front of one at that pixel move too, by at most its weight times a
/// feature, which tolerances cover.
pub fn near_cutoffs(gs: &[Gaussian], cam: &Camera) -> NearCutoffs {
    let vis = sorted_visible(gs, cam);
    let mut slack = vec![0.0; cam.pixels() as usize];
    let mut gaussians = vec![false; gs.len()];
    let near = |value: f64, threshold: f64, margin: f64| (value / threshold - 1.0).abs() < margin;
    for py in 0..cam.height {
        for px in 0..cam.width {
            let (tile_x, tile_y) = (px / TILE_SIZE, py / TILE_SIZE);
            let pixel_slack = &mut slack[(py * cam.width + px) as usize];
            let mut t = 1.0f64;
            // The previous contributor: index, depth, weight αT.
            let mut last: Option<(usize, f64, f64)> = None;
            for &(gi, ref p) in &vis {
                if !covers_tile(p, tile_x, tile_y) {
                    continue;
                }
                let Some((_, v)) = falloff(p, px, py) else {
                    continue;
                };
                let raw = p.opacity * v;
                if near(raw, MIN_ALPHA, ALPHA_MARGIN) {
                    gaussians[gi] = true;
                    *pixel_slack += 2.0 * raw * t;
                }
                if near(raw, MAX_ALPHA, ALPHA_MARGIN) {
                    gaussians[gi] = true;
                }
                let alpha = raw.min(MAX_ALPHA);
                if alpha < MIN_ALPHA {
                    continue;
                }
                if let Some((prev, z, weight)) = last {
                    if near(p.depth, z, DEPTH_MARGIN) {
                        gaussians[prev] = true;
                        gaussians[gi] = true;
                        *pixel_slack += weight * alpha;
                    }
                }
                last = Some((gi, p.depth, alpha * t));
                let next = t * (1.0 - alpha);
                if near(next, MIN_TRANSMITTANCE, ALPHA_MARGIN) {
                    gaussians[gi] = true;
                    *pixel_slack += alpha * t + 2.0 * MIN_TRANSMITTANCE;
                }
                if next < MIN_TRANSMITTANCE {
                    break;
                }
                t = next;
            }
        }
    }
    NearCutoffs { slack, gaussians }
}
