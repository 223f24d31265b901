//! Front-to-back blending per pixel over the tile lists, and the work it
//! takes.

#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use latentam_base::Camera;
use latentam_shaders::shared::TILE_SIZE;

use super::gaussian::*;
use super::projection::*;

pub(crate) fn features(g: &Gaussian, p: &Projected) -> [f64; CHANNELS] {
    let mut f = [0.0; CHANNELS];
    f[..3].copy_from_slice(&g.color);
    f[3] = p.depth;
    f[4..].copy_from_slice(&g.query);
    f
}

/// Visible Gaussians of a view in blending order, with their projections.
pub(crate) fn sorted_visible(gs: &[Gaussian], cam: &Camera) -> Vec<(usize, Projected)> {
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
pub(crate) fn covers_tile(p: &Projected, tile_x: u32, tile_y: u32) -> bool {
    let [x0, y0, x1, y1] = p.tiles;
    (x0..=x1).contains(&tile_x) && (y0..=y1).contains(&tile_y)
}

/// d = m − p and e^(−σ) of `p` at pixel (`px`, `py`); `None` where σ < 0
/// (a conic that is not positive definite there), which blending skips.
pub(crate) fn falloff(p: &Projected, px: u32, py: u32) -> Option<([f64; 2], f64)> {
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
pub(crate) struct Contribution {
    pub(crate) list_index: usize,
    pub(crate) alpha: f64,
    pub(crate) vis: f64,
    pub(crate) t: f64,
    pub(crate) d: [f64; 2],
}

/// Walks one pixel front to back; returns the contributions, the final T
/// and how many of the Gaussians covering the pixel's tile it tested.
pub(crate) fn blend_pixel(
    vis: &[(usize, Projected)],
    px: u32,
    py: u32,
) -> (Vec<Contribution>, f64, usize) {
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
