//! The Gaussian rasterizer's math in f64: projection, tile culling,
//! front-to-back blending, and the backward pass to every parameter.
//!
//! GPU kernels: `glsl/project_forward.comp`, `glsl/raster_forward.comp`,
//! `shaders/wgsl/raster_backward.wgsl`, `glsl/project_backward.comp`
//! (orchestrated by `latentam_core::splat::Rasterizer`).
//!
//! Conventions (see [`Camera`] for the pixel convention):
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

use glam::{DMat3, DVec3};

use latentam_base::{Camera, HostGaussians, QUERY_DIM};
use latentam_shaders::shared;
use latentam_shaders::shared::TILE_SIZE;

pub mod cutoffs;

// The kernels' thresholds (shaders/layouts.rs), at the f32 values they
// compare against.
/// Largest alpha a single Gaussian may contribute.
pub const MAX_ALPHA: f64 = shared::MAX_ALPHA as f64;
/// Contributions with smaller alpha are skipped.
pub const MIN_ALPHA: f64 = shared::MIN_ALPHA as f64;
/// A pixel stops when its transmittance would fall below this.
pub const MIN_TRANSMITTANCE: f64 = shared::MIN_TRANSMITTANCE as f64;
/// Low-pass filter added to the 2-D covariance (pixels²).
pub const LOW_PASS: f64 = shared::LOW_PASS as f64;
pub use latentam_base::GUARD_BAND;

/// One Gaussian's parameters in f64.
///
/// ```
/// use latentam_reference::raster::{project, Gaussian};
/// use latentam_base::{Camera, HostGaussians};
///
/// let mut host = HostGaussians::zeros(1);
/// host.means[0] = [0.0, 0.0, 2.0];
/// host.quats[0] = [1.0, 0.0, 0.0, 0.0];
/// host.log_scales[0] = [-2.0; 3];
/// let g = Gaussian::from_host(&host, 0); // widened to f64
/// assert_eq!(g.mean, [0.0, 0.0, 2.0]);
/// assert!(project(&g, &Camera::at_origin(32, 24)).is_some());
/// ```
#[derive(Clone, Copy, Debug)]
pub struct Gaussian {
    /// Centre.
    pub mean: [f64; 3],
    /// Log scale.
    pub log_scale: [f64; 3],
    /// Quaternion (w, x, y, z), unnormalised.
    pub quat: [f64; 4],
    /// Colour.
    pub color: [f64; 3],
    /// Opacity logit.
    pub opacity_logit: f64,
    /// Query.
    pub query: [f64; QUERY_DIM],
}

impl Gaussian {
    /// Gaussian `i` of a host set, widened to f64.
    pub fn from_host(h: &HostGaussians, i: usize) -> Self {
        let w = |a: &[f32]| a.iter().map(|&v| v as f64).collect::<Vec<_>>();
        Self {
            mean: w(&h.means[i]).try_into().unwrap(),
            log_scale: w(&h.log_scales[i]).try_into().unwrap(),
            quat: w(&h.quats[i]).try_into().unwrap(),
            color: w(&h.colors[i]).try_into().unwrap(),
            opacity_logit: h.opacity_logits[i] as f64,
            query: w(&h.queries[i]).try_into().unwrap(),
        }
    }

    /// All Gaussians of a host set.
    pub fn all(h: &HostGaussians) -> Vec<Self> {
        (0..h.means.len()).map(|i| Self::from_host(h, i)).collect()
    }

    fn opacity(&self) -> f64 {
        sigmoid(self.opacity_logit)
    }
}

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// Rotation matrix of a unit quaternion (w, x, y, z).
pub fn quat_to_rotmat(q: [f64; 4]) -> DMat3 {
    let [w, x, y, z] = q;
    // Each inner array is a column of R.
    DMat3::from_cols_array_2d(&[
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y + w * z),
            2.0 * (x * z - w * y),
        ],
        [
            2.0 * (x * y - w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z + w * x),
        ],
        [
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ])
}

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
struct ProjectionState {
    rot: DMat3,   // R(q̂)
    scale: DVec3, // s
    m: DMat3,     // R(q̂)·diag(s)
    w: DMat3,     // world-to-camera rotation
    t: DVec3,     // camera-frame centre (unclamped)
    cov_c: DMat3, // W Σ Wᵀ
    j: [[f64; 3]; 2],
    clamped: [bool; 2],
    lim: [f64; 2], // the clamped tx/tz, ty/tz when clamped
}

fn project_state(g: &Gaussian, cam: &Camera) -> Option<(Projected, ProjectionState)> {
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

/// Channels blended per pixel besides alpha: RGB, depth, query.
pub const CHANNELS: usize = 4 + QUERY_DIM;

/// One rendered view.
///
/// ```
/// use latentam_reference::raster::{render, Gaussian};
/// use latentam_base::Camera;
///
/// let cam = Camera::at_origin(32, 24);
/// let g = Gaussian { mean: [0.0, 0.0, 2.0], log_scale: [-2.0; 3], quat: [1.0, 0.0, 0.0, 0.0],
///     color: [1.0, 0.0, 0.0], opacity_logit: 2.0, query: [0.0; 32] };
/// let img = render(&[g], &cam, [0.0; 3]);
/// let centre = &img.channels[12 * 32 + 16];
/// assert!(img.alpha[12 * 32 + 16] > 0.5);
/// // Red over black; channel 3 is the depth Σ w·z, not normalised by alpha.
/// assert!(centre[0] > 0.5 && centre[1] == 0.0);
/// assert!((centre[3] - 2.0 * img.alpha[12 * 32 + 16]).abs() < 1e-9);
/// ```
#[derive(Clone, Debug)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Per pixel (row-major): RGB with background, depth, then the query.
    pub channels: Vec<[f64; CHANNELS]>,
    /// Per pixel: accumulated alpha 1 − T.
    pub alpha: Vec<f64>,
}

/// Upstream gradients of one view, laid out like [`Image`].
///
/// ```
/// use latentam_reference::raster::{backward, Gaussian, ImageGrads, CHANNELS};
/// use latentam_base::Camera;
///
/// let cam = Camera::at_origin(32, 24);
/// let g = Gaussian { mean: [0.0, 0.0, 2.0], log_scale: [-2.0; 3], quat: [1.0, 0.0, 0.0, 0.0],
///     color: [1.0, 0.0, 0.0], opacity_logit: 2.0, query: [0.0; 32] };
/// // L = Σ red over the image: ∂L/∂R = 1 at every pixel, 0 elsewhere.
/// let n = cam.pixels() as usize;
/// let mut up = ImageGrads { channels: vec![[0.0; CHANNELS]; n], alpha: vec![0.0; n] };
/// up.channels.iter_mut().for_each(|c| c[0] = 1.0);
/// let grads = backward(&[g], &[cam], [0.0; 3], &[up], true);
/// assert!(grads.grads[0].color[0] > 0.0 && grads.grads[0].color[1] == 0.0);
/// ```
#[derive(Clone, Debug)]
pub struct ImageGrads {
    /// ∂L/∂(RGB, depth, query) per pixel.
    pub channels: Vec<[f64; CHANNELS]>,
    /// ∂L/∂alpha per pixel.
    pub alpha: Vec<f64>,
}

fn features(g: &Gaussian, p: &Projected) -> [f64; CHANNELS] {
    let mut f = [0.0; CHANNELS];
    f[..3].copy_from_slice(&g.color);
    f[3] = p.depth;
    f[4..].copy_from_slice(&g.query);
    f
}

/// Visible Gaussians of a view in blending order, with their projections.
fn sorted_visible(gs: &[Gaussian], cam: &Camera) -> Vec<(usize, Projected)> {
    let mut vis: Vec<(usize, Projected)> = gs
        .iter()
        .enumerate()
        .filter_map(|(i, g)| project(g, cam).map(|p| (i, p)))
        .collect();
    // Ties keep index order, as the GPU's stable sort does.
    vis.sort_by(|a, b| a.1.depth.total_cmp(&b.1.depth).then(a.0.cmp(&b.0)));
    vis
}

/// Whether `p`'s tile rectangle covers tile (`tile_x`, `tile_y`).
fn covers_tile(p: &Projected, tile_x: u32, tile_y: u32) -> bool {
    let [x0, y0, x1, y1] = p.tiles;
    (x0..=x1).contains(&tile_x) && (y0..=y1).contains(&tile_y)
}

/// d = m − p and e^(−σ) of `p` at pixel (`px`, `py`); `None` where σ < 0
/// (a conic that is not positive definite there), which blending skips.
fn falloff(p: &Projected, px: u32, py: u32) -> Option<([f64; 2], f64)> {
    let d = [p.mean2d[0] - px as f64, p.mean2d[1] - py as f64];
    let [a, b, c] = p.conic;
    let sigma = 0.5 * (a * d[0] * d[0] + c * d[1] * d[1]) + b * d[0] * d[1];
    if sigma < 0.0 {
        return None;
    }
    Some((d, (-sigma).exp()))
}

/// A contribution to a pixel: which Gaussian, its alpha, e^(−σ), the
/// transmittance in front of it, and d = m − p.
struct Contribution {
    list_index: usize,
    alpha: f64,
    vis: f64,
    t: f64,
    d: [f64; 2],
}

/// Walks one pixel front to back; returns the contributions, the final T
/// and how many of the Gaussians covering the pixel's tile it tested.
fn blend_pixel(vis: &[(usize, Projected)], px: u32, py: u32) -> (Vec<Contribution>, f64, usize) {
    let (tile_x, tile_y) = (px / TILE_SIZE, py / TILE_SIZE);
    let mut t = 1.0;
    let mut out = Vec::new();
    let mut tested = 0;
    for (k, (_, p)) in vis.iter().enumerate() {
        if !covers_tile(p, tile_x, tile_y) {
            continue;
        }
        tested += 1;
        let Some((d, v)) = falloff(p, px, py) else {
            continue;
        };
        let alpha = (p.opacity * v).min(MAX_ALPHA);
        if alpha < MIN_ALPHA {
            continue;
        }
        let next = t * (1.0 - alpha);
        if next < MIN_TRANSMITTANCE {
            break;
        }
        out.push(Contribution {
            list_index: k,
            alpha,
            vis: v,
            t,
            d,
        });
        t = next;
    }
    (out, t, tested)
}

/// How much per-pixel blending work one view takes: the counts a cost model
/// of the blending kernels needs.
///
/// ```
/// use latentam_reference::raster::{blend_work, Gaussian};
/// use latentam_base::Camera;
///
/// let g = Gaussian { mean: [0.0, 0.0, 2.0], log_scale: [-2.0; 3], quat: [1.0, 0.0, 0.0, 0.0],
///     color: [1.0, 0.0, 0.0], opacity_logit: 2.0, query: [0.0; 32] };
/// let work = blend_work(&[g], &Camera::at_origin(32, 24));
/// assert!(work.contributing > 0 && work.contributing <= work.tested);
/// assert!(work.tile_entries_contributing <= work.tile_entries_walked);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BlendWork {
    /// (pixel, Gaussian) pairs the forward pass tests: every entry of the
    /// pixel's tile list up to the one that saturates it, or all of them.
    pub tested: u64,
    /// Pairs the backward pass tests: every entry up to the pixel's last
    /// contributor.
    pub tested_backward: u64,
    /// Pairs that contribute to the pixel (blended in forward, differentiated
    /// in backward).
    pub contributing: u64,
    /// (tile, list entry) pairs walked by a tile until every pixel of it is
    /// saturated (or its list ends): the work of kernels that move a whole
    /// tile through its list in step.
    pub tile_entries_walked: u64,
    /// (tile, list entry) pairs up to the tile's last contributor.
    pub tile_entries_walked_backward: u64,
    /// (tile, list entry) pairs that contribute to at least one pixel of
    /// the tile.
    pub tile_entries_contributing: u64,
}

/// Counts the blending work of one view (see [`BlendWork`]), walking each
/// tile's list as the kernels do.
pub fn blend_work(gs: &[Gaussian], cam: &Camera) -> BlendWork {
    let vis = sorted_visible(gs, cam);
    let tiles_x = cam.width.div_ceil(TILE_SIZE);
    let tiles_y = cam.height.div_ceil(TILE_SIZE);
    let mut lists: Vec<Vec<(usize, Projected)>> = vec![Vec::new(); (tiles_x * tiles_y) as usize];
    for &(i, p) in &vis {
        let [x0, y0, x1, y1] = p.tiles;
        for ty in y0..=y1 {
            for tx in x0..=x1 {
                lists[(ty * tiles_x + tx) as usize].push((i, p));
            }
        }
    }
    let mut work = BlendWork::default();
    let n_tiles = lists.len();
    let mut walked = vec![0u64; n_tiles];
    let mut walked_backward = vec![0u64; n_tiles];
    let mut contributes: Vec<Vec<bool>> = lists.iter().map(|l| vec![false; l.len()]).collect();
    for py in 0..cam.height {
        for px in 0..cam.width {
            let tile = ((py / TILE_SIZE) * tiles_x + px / TILE_SIZE) as usize;
            let (contribs, _, tested) = blend_pixel(&lists[tile], px, py);
            let last = contribs.last().map_or(0, |c| c.list_index as u64 + 1);
            work.tested += tested as u64;
            work.contributing += contribs.len() as u64;
            work.tested_backward += last;
            walked[tile] = walked[tile].max(tested as u64);
            walked_backward[tile] = walked_backward[tile].max(last);
            for c in &contribs {
                contributes[tile][c.list_index] = true;
            }
        }
    }
    work.tile_entries_walked = walked.iter().sum();
    work.tile_entries_walked_backward = walked_backward.iter().sum();
    work.tile_entries_contributing = contributes
        .iter()
        .map(|c| c.iter().filter(|&&b| b).count() as u64)
        .sum();
    work
}

/// Renders one view.
pub fn render(gs: &[Gaussian], cam: &Camera, background: [f64; 3]) -> Image {
    let vis = sorted_visible(gs, cam);
    let n = cam.pixels() as usize;
    let mut channels = vec![[0.0; CHANNELS]; n];
    let mut alpha = vec![0.0; n];
    for py in 0..cam.height {
        for px in 0..cam.width {
            let i = (py * cam.width + px) as usize;
            let (contribs, t, _) = blend_pixel(&vis, px, py);
            for c in &contribs {
                let (gi, p) = &vis[c.list_index];
                let f = features(&gs[*gi], p);
                for k in 0..CHANNELS {
                    channels[i][k] += c.alpha * c.t * f[k];
                }
            }
            for k in 0..3 {
                channels[i][k] += t * background[k];
            }
            alpha[i] = 1.0 - t;
        }
    }
    Image {
        width: cam.width,
        height: cam.height,
        channels,
        alpha,
    }
}

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
struct ProjectedGrads {
    mean2d: [f64; 2],
    conic: [f64; 3],
    depth: f64,
    opacity: f64,
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
fn projection_backward(g: &Gaussian, cam: &Camera, pg: &ProjectedGrads, out: &mut Gaussian) {
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
fn quat_to_rotmat_vjp(q: [f64; 4], v_r: &DMat3) -> [f64; 4] {
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
