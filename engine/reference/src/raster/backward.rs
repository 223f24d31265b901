//! The backward pass: image gradients to every Gaussian parameter.

#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use glam::{DMat3, DVec3};

use latentam_base::{Camera, QUERY_DIM};

use super::blend::*;
use super::gaussian::*;
use super::projection::*;

/// Gradients of every Gaussian parameter, laid out like [`Gaussian`].
///
/// ```
/// use latentam_reference::raster::{backward, Gaussian, ImageGrads, CHANNELS};
/// use latentam_base::Camera;
///
/// let cam = Camera::at_origin(32, 24);
/// let g = Gaussian { mean: [0.0, 0.0, 2.0], log_scale: [-2.0; 3], quat: [1.0, 0.0, 0.0, 0.0],
///     color: [1.0, 0.0, 0.0], opacity_logit: 2.0, query: [0.0; 32] };
/// let n = cam.pixels() as usize;
/// let mut up = ImageGrads { channels: vec![[0.0; CHANNELS]; n], alpha: vec![0.0; n] };
/// up.channels.iter_mut().for_each(|c| c[0] = 1.0); // L = Σ red
/// let grads = backward(&[g], &[cam], [0.0; 3], &[up], true).grads;
/// // More opacity means more red over a black background.
/// assert!(grads[0].opacity_logit > 0.0);
/// ```
#[derive(Clone, Debug)]
pub struct GaussianGrads {
    /// One entry per Gaussian.
    pub grads: Vec<Gaussian>,
}

/// Gradients of a Gaussian's projection outputs (image mean, conic, depth,
/// opacity) in one view.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct ProjectedGrads {
    mean2d: [f64; 2],
    pub(crate) conic: [f64; 3],
    pub(crate) depth: f64,
    pub(crate) opacity: f64,
}

/// Backward pass over a batch of views: given ∂L/∂(every output pixel),
/// returns ∂L/∂(every Gaussian parameter). With `detach_query` the query
/// channels' gradients reach only the queries (not opacity or geometry).
pub fn backward(
    gs: &[Gaussian],
    cams: &[Camera],
    background: [f64; 3],
    upstream: &[ImageGrads],
    detach_query: bool,
) -> GaussianGrads {
    let zero = Gaussian {
        mean: [0.0; 3],
        log_scale: [0.0; 3],
        quat: [0.0; 4],
        color: [0.0; 3],
        opacity_logit: 0.0,
        query: [0.0; QUERY_DIM],
    };
    let mut out = vec![zero; gs.len()];
    for (cam, up) in cams.iter().zip(upstream) {
        let vis = sorted_visible(gs, cam);
        let mut pgrads = vec![ProjectedGrads::default(); vis.len()];
        for py in 0..cam.height {
            for px in 0..cam.width {
                let i = (py * cam.width + px) as usize;
                let (contribs, t_final, _) = blend_pixel(&vis, px, py);
                let v_c = &up.channels[i];
                let v_alpha_out = up.alpha[i];
                // Colour channels without background; Σ_{j>i} w_j f_j is the
                // suffix sum, accumulated back to front.
                let mut suffix = [0.0; CHANNELS];
                let bg_dot: f64 = (0..3).map(|k| background[k] * v_c[k]).sum();
                for c in contribs.iter().rev() {
                    let (gi, p) = &vis[c.list_index];
                    let g = &gs[*gi];
                    let f = features(g, p);
                    let w = c.alpha * c.t;
                    let ra = 1.0 / (1.0 - c.alpha);
                    // ∂out_k/∂α = f_k T − suffix_k/(1−α) (− T_final bg_k/(1−α)
                    // for colour), ∂alpha_out/∂α = T_final/(1−α).
                    let geom_channels = if detach_query { 4 } else { CHANNELS };
                    let mut v_a = (v_alpha_out - bg_dot) * t_final * ra;
                    for k in 0..geom_channels {
                        v_a += v_c[k] * (f[k] * c.t - suffix[k] * ra);
                    }
                    for k in 0..CHANNELS {
                        suffix[k] += w * f[k];
                    }
                    let og = &mut out[*gi];
                    for k in 0..3 {
                        og.color[k] += w * v_c[k];
                    }
                    for k in 0..QUERY_DIM {
                        og.query[k] += w * v_c[4 + k];
                    }
                    let pg = &mut pgrads[c.list_index];
                    pg.depth += w * v_c[3];
                    // α = o·e^(−σ) unless clamped at MAX_ALPHA.
                    if p.opacity * c.vis <= MAX_ALPHA {
                        let v_sigma = -p.opacity * c.vis * v_a;
                        let [dx, dy] = c.d;
                        let [a, b, cc] = p.conic;
                        pg.conic[0] += 0.5 * v_sigma * dx * dx;
                        pg.conic[1] += v_sigma * dx * dy;
                        pg.conic[2] += 0.5 * v_sigma * dy * dy;
                        pg.mean2d[0] += v_sigma * (a * dx + b * dy);
                        pg.mean2d[1] += v_sigma * (b * dx + cc * dy);
                        pg.opacity += c.vis * v_a;
                    }
                }
            }
        }
        for ((gi, _), pg) in vis.iter().zip(&pgrads) {
            projection_backward(&gs[*gi], cam, pg, &mut out[*gi]);
        }
    }
    GaussianGrads { grads: out }
}

/// Chain rule from one view's projected gradients to the parameters;
/// adds into `out`.
//
// Long because it is one chain rule written out in the order of the
// kernel it checks (`glsl/project_backward.comp`): opacity, conic, 2-D
// covariance, Jacobian, mean, scale and rotation, each step beside its
// counterpart there.
pub(crate) fn projection_backward(
    g: &Gaussian,
    cam: &Camera,
    pg: &ProjectedGrads,
    out: &mut Gaussian,
) {
    let (p, st) = project_state(g, cam).expect("visible Gaussian projects");
    let o = p.opacity;
    out.opacity_logit += pg.opacity * o * (1.0 - o);

    // Conic = Σ₂⁻¹: ∂L/∂Σ₂ = −Σ₂⁻¹ V Σ₂⁻¹, V symmetric with the off-diagonal
    // gradient split over both entries.
    let [a, b, c] = p.conic;
    let conic = [[a, b], [b, c]];
    let v = [
        [pg.conic[0], 0.5 * pg.conic[1]],
        [0.5 * pg.conic[1], pg.conic[2]],
    ];
    let mut v_cov2d = [[0.0; 2]; 2];
    for r in 0..2 {
        for s in 0..2 {
            for k in 0..2 {
                for l in 0..2 {
                    v_cov2d[r][s] -= conic[r][k] * v[k][l] * conic[l][s];
                }
            }
        }
    }

    // Σ₂ = J Σc Jᵀ: ∂L/∂Σc = Jᵀ V₂ J, ∂L/∂J = 2 V₂ J Σc (both symmetric).
    let j = st.j;
    let cov_c = st.cov_c.to_cols_array_2d(); // symmetric, so rows = cols
    let mut v_cov_c = [[0.0; 3]; 3];
    for r in 0..3 {
        for s in 0..3 {
            for k in 0..2 {
                for l in 0..2 {
                    v_cov_c[r][s] += j[k][r] * v_cov2d[k][l] * j[l][s];
                }
            }
        }
    }
    let mut v_j = [[0.0; 3]; 2];
    for r in 0..2 {
        for s in 0..3 {
            for k in 0..2 {
                for l in 0..3 {
                    v_j[r][s] += 2.0 * v_cov2d[r][k] * j[k][l] * cov_c[l][s];
                }
            }
        }
    }

    // Image mean from the unclamped t; J from the clamped one.
    let t = st.t;
    let (fx, fy) = (cam.fx, cam.fy);
    let tz = t.z;
    let mut v_t = DVec3::new(
        fx / tz * pg.mean2d[0],
        fy / tz * pg.mean2d[1],
        -(fx * t.x * pg.mean2d[0] + fy * t.y * pg.mean2d[1]) / (tz * tz),
    );
    v_t.z += pg.depth;
    // J00 = fx/tz, J11 = fy/tz.
    v_t.z += -fx / (tz * tz) * v_j[0][0] - fy / (tz * tz) * v_j[1][1];
    // J02 = −fx·u/tz with u = tx/tz, clamped or not.
    for (axis, f) in [(0usize, fx), (1usize, fy)] {
        let vj = v_j[axis][2];
        if st.clamped[axis] {
            // u fixed at the limit: J02 = −f·lim/tz.
            v_t.z += f * st.lim[axis] / (tz * tz) * vj;
        } else {
            // J02 = −f·t_a/tz².
            let ta = if axis == 0 { t.x } else { t.y };
            v_t[axis] += -f / (tz * tz) * vj;
            v_t.z += 2.0 * f * ta / (tz * tz * tz) * vj;
        }
    }

    // Camera frame to world: t = Wμ + w, Σc = W Σ Wᵀ.
    let w = st.w;
    let v_mean = w.transpose() * v_t;
    for k in 0..3 {
        out.mean[k] += v_mean[k];
    }
    let v_cov_c = DMat3::from_cols_array_2d(&v_cov_c).transpose();
    let v_cov = w.transpose() * v_cov_c * w;

    // Σ = M Mᵀ, M = R diag(s): ∂L/∂M = 2 ∂L/∂Σ M (∂L/∂Σ symmetric).
    let v_m = 2.0 * v_cov * st.m;
    let s = st.scale;
    let mut v_rot = DMat3::ZERO;
    for i in 0..3 {
        let v_s = st.rot.col(i).dot(v_m.col(i));
        out.log_scale[i] += v_s * s[i];
        *v_rot.col_mut(i) = v_m.col(i) * s[i];
    }

    // R(q̂) → q̂ → q (normalisation).
    let qn = g.quat.iter().map(|v| v * v).sum::<f64>().sqrt();
    let q = g.quat.map(|v| v / qn);
    let v_qhat = quat_to_rotmat_vjp(q, &v_rot);
    let dot: f64 = (0..4).map(|k| v_qhat[k] * q[k]).sum();
    for k in 0..4 {
        out.quat[k] += (v_qhat[k] - dot * q[k]) / qn;
    }
}

/// ∂L/∂q̂ given ∂L/∂R for R = [`quat_to_rotmat`](q̂).
pub(crate) fn quat_to_rotmat_vjp(q: [f64; 4], v_r: &DMat3) -> [f64; 4] {
    let [w, x, y, z] = q;
    // r(i, j) = ∂L/∂R[row i][col j].
    let r = |i: usize, j: usize| v_r.col(j)[i];
    [
        2.0 * (-z * r(0, 1) + y * r(0, 2) + z * r(1, 0) - x * r(1, 2) - y * r(2, 0) + x * r(2, 1)),
        2.0 * (y * r(0, 1) + z * r(0, 2) + y * r(1, 0) - 2.0 * x * r(1, 1) - w * r(1, 2)
            + z * r(2, 0)
            + w * r(2, 1)
            - 2.0 * x * r(2, 2)),
        2.0 * (-2.0 * y * r(0, 0) + x * r(0, 1) + w * r(0, 2) + x * r(1, 0) + z * r(1, 2)
            - w * r(2, 0)
            + z * r(2, 1)
            - 2.0 * y * r(2, 2)),
        2.0 * (-2.0 * z * r(0, 0) - w * r(0, 1) + x * r(0, 2) + w * r(1, 0) - 2.0 * z * r(1, 1)
            + y * r(1, 2)
            + x * r(2, 0)
            + y * r(2, 1)),
    ]
}
