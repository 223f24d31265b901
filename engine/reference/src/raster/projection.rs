//! Projection of a Gaussian into a camera: image mean, 2-D covariance,
//! conic and tile rectangle.

#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use glam::{DMat3, DVec3};

use latentam_base::Camera;
use latentam_shaders::shared::TILE_SIZE;

use super::gaussian::*;

/// A Gaussian as one camera sees it.
///
/// ```
/// use latentam_reference::raster::{project, Gaussian};
/// use latentam_base::Camera;
///
/// let cam = Camera::at_origin(32, 24);
/// let g = Gaussian { mean: [0.0, 0.0, 2.0], log_scale: [-2.0; 3], quat: [1.0, 0.0, 0.0, 0.0],
///     color: [1.0, 0.0, 0.0], opacity_logit: 2.0, query: [0.0; 32] };
/// let p = project(&g, &cam).expect("in view");
/// // On the optical axis: at the principal point, 2 m deep.
/// assert!((p.mean2d[0] - cam.cx).abs() < 1e-9 && (p.mean2d[1] - cam.cy).abs() < 1e-9);
/// assert!((p.depth - 2.0).abs() < 1e-12);
/// assert!(p.opacity > 0.88);
/// ```
#[derive(Clone, Copy, Debug)]
pub struct Projected {
    /// Image-plane centre m.
    pub mean2d: [f64; 2],
    /// Conic (a, b, c): the inverse 2-D covariance [[a, b], [b, c]].
    pub conic: [f64; 3],
    /// Camera-frame depth tz of the centre.
    pub depth: f64,
    /// Opacity o.
    pub opacity: f64,
    /// Covered tiles, inclusive: (x0, y0, x1, y1).
    pub tiles: [u32; 4],
}

/// Intermediate values of the projection, kept for its backward pass.
pub(crate) struct ProjectionState {
    pub(crate) rot: DMat3,   // R(q̂)
    pub(crate) scale: DVec3, // s
    pub(crate) m: DMat3,     // R(q̂)·diag(s)
    pub(crate) w: DMat3,     // world-to-camera rotation
    pub(crate) t: DVec3,     // camera-frame centre (unclamped)
    pub(crate) cov_c: DMat3, // W Σ Wᵀ
    pub(crate) j: [[f64; 3]; 2],
    pub(crate) clamped: [bool; 2],
    pub(crate) lim: [f64; 2], // the clamped tx/tz, ty/tz when clamped
}

pub(crate) fn project_state(g: &Gaussian, cam: &Camera) -> Option<(Projected, ProjectionState)> {
    let view = cam.world_to_cam();
    let w = view.matrix3;
    let t = w * DVec3::from(g.mean) + view.translation;
    if !(t.z >= cam.near && t.z <= cam.far) {
        return None;
    }
    let qn = (g.quat.iter().map(|v| v * v).sum::<f64>()).sqrt();
    if !(qn > 1e-12) || !qn.is_finite() {
        return None;
    }
    let rot = quat_to_rotmat(g.quat.map(|v| v / qn));
    let scale = DVec3::from(g.log_scale.map(f64::exp));
    let m = rot * DMat3::from_diagonal(scale);
    let cov = m * m.transpose();
    let cov_c = w * cov * w.transpose();

    let (fx, fy) = (cam.fx, cam.fy);
    let [lo_x, hi_x, lo_y, hi_y] = cam.guard_band();
    let (lim_x, lim_y) = ([lo_x, hi_x], [lo_y, hi_y]);
    let (rx, ry) = (t.x / t.z, t.y / t.z);
    let cx_ = rx.clamp(lim_x[0], lim_x[1]);
    let cy_ = ry.clamp(lim_y[0], lim_y[1]);
    let clamped = [cx_ != rx, cy_ != ry];
    let (tx, ty, tz) = (t.z * cx_, t.z * cy_, t.z);
    let j = [
        [fx / tz, 0.0, -fx * tx / (tz * tz)],
        [0.0, fy / tz, -fy * ty / (tz * tz)],
    ];
    // Σ₂ = J Σc Jᵀ (+ low pass), as (a, b, c) of [[a, b], [b, c]].
    let jm = |r: usize| DVec3::new(j[r][0], j[r][1], j[r][2]);
    let (j0, j1) = (jm(0), jm(1));
    let cov2d = [
        j0.dot(cov_c * j0) + LOW_PASS,
        j0.dot(cov_c * j1),
        j1.dot(cov_c * j1) + LOW_PASS,
    ];
    let det = cov2d[0] * cov2d[2] - cov2d[1] * cov2d[1];
    if !(det > 0.0) {
        return None;
    }
    let conic = [cov2d[2] / det, -cov2d[1] / det, cov2d[0] / det];
    let mean2d = [fx * t.x / t.z + cam.cx, fy * t.y / t.z + cam.cy];
    let opacity = g.opacity();
    if !(opacity >= MIN_ALPHA) {
        return None;
    }
    let ext = (2.0 * (opacity / MIN_ALPHA).ln()).sqrt().min(3.33);
    let rad = [
        (ext * cov2d[0].sqrt()).ceil(),
        (ext * cov2d[2].sqrt()).ceil(),
    ];
    let size = [cam.width as f64, cam.height as f64];
    let mut tiles = [0u32; 4];
    for a in 0..2 {
        let lo = mean2d[a] - rad[a];
        let hi = mean2d[a] + rad[a];
        if !(hi >= 0.0 && lo <= size[a] - 1.0) {
            return None;
        }
        tiles[a] = (lo.max(0.0) / TILE_SIZE as f64).floor() as u32;
        tiles[a + 2] = (hi.min(size[a] - 1.0) / TILE_SIZE as f64).floor() as u32;
    }
    Some((
        Projected {
            mean2d,
            conic,
            depth: t.z,
            opacity,
            tiles,
        },
        ProjectionState {
            rot,
            scale,
            m,
            w,
            t,
            cov_c,
            j,
            clamped,
            lim: [cx_, cy_],
        },
    ))
}

/// Projects one Gaussian; `None` when it is culled (behind the near plane,
/// past the far plane, off-screen, too transparent, or invalid).
pub fn project(g: &Gaussian, cam: &Camera) -> Option<Projected> {
    project_state(g, cam).map(|(p, _)| p)
}
