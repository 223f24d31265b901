//! New Gaussians from a keyframe: back-projected depth where the map does
//! not yet explain the view, one per free voxel.

use std::collections::HashSet;

use glam::DVec3;

use super::global::{Gaussian, GlobalMap};
use super::voxel::VoxelKey;
use crate::splat::{PixelGrid, QUERY_DIM};
use latentam_base::random::SplitMix;
use latentam_base::settings;
use latentam_base::settings::{Setting, MAX_DISTANCE};
use latentam_io::{DepthImage, Frame};

settings! {
    /// How Gaussians are seeded (the paper gives no rule; SplaTAM's projective, isotropic
    /// variant: scale from depth over focal length, identity rotation).
    ///
    /// ```
    /// use latentam_core::map::SeedingConfig;
    ///
    /// // Denser seeds, only up to 5 m (a small room, a noisy sensor).
    /// let seeding = SeedingConfig { stride: 1, max_depth: 5.0, ..SeedingConfig::default() };
    /// let config = latentam_core::mapper::MapperConfig { seeding, ..Default::default() };
    /// ```
    #[derive(Copy)]
    pub struct SeedingConfig {
        // A pixel count fixes the map's density in the image, not in the
        // world: at 1280×720 every 2nd pixel seeded four times the
        // Gaussians of 640×480 for the same room, each a quarter the size,
        // and views between keyframes saw through the gaps (the demo
        // scene at 1280×720: 20.7 dB on novel views at stride 2, 22.9 at
        // 3 with 65 % of the Gaussians and a better depth). One candidate
        // per 3.3 mrad gives 640×480 lenses (f ≈ 480–620 px) the stride 2
        // the ablation chose there and 1280×720 ones (f ≈ 900–1000) 3.
        /// Every stride-th pixel along rows and columns is a candidate; 0
        /// picks it from the focal length f (pixels): one candidate per 3.3
        /// milliradians of view, round(f / 300), at least 2 (every 2nd pixel
        /// at 640×480, every 3rd at 1280×720 with the usual lenses), so the
        /// map's density does not depend on the camera's resolution.
        pub stride: u32 = 0 => value().range(0u32, 64u32),
        /// Depths beyond this (metres) are not seeded.
        pub max_depth: f32 = 10.0 => value().above(0.0, MAX_DISTANCE).unit("metres"),
        /// A pixel is unexplained, and may be seeded, where the rendered
        /// (accumulated) alpha is below this.
        pub alpha_threshold: f32 = 0.5 => value().range(0.0, 1.0),
        /// ... or where the rendered depth is off by more than this
        /// fraction of the measured depth (0.05 = 5 %).
        pub depth_error: f32 = 0.05 => value().range(0.0, MAX_DEPTH_ERROR),
        // High, because a Gaussian gets few steps online: seeded at 0.5,
        // surfaces stayed half transparent over the black background (a
        // keyframe rendered at its own pose right after seeding: 18.5 dB
        // at 0.5, 23.8 dB at 0.9 with `scale_factor` 0.75, on 7-Scenes).
        /// Initial opacity of new Gaussians.
        pub opacity: f32 = 0.9 => value().range(0.0, 1.0),
        /// Initial standard deviation of new Gaussians as a multiple of the
        /// spacing between seeds (stride x depth / focal length); at least
        /// half a voxel in any case.
        pub scale_factor: f32 = 0.75 => value().above(0.0, MAX_SCALE_FACTOR),
        // Partial alpha and depth disagreements at edges come with every
        // revisit from a new position; seeding them would grow the map
        // with time rather than with the space (and detail) explored.
        /// Where the map already has a Gaussian within the seed spacing
        /// (stride x depth / focal), a pixel is seeded only if the rendered
        /// alpha is below this (a hole); partial alpha or depth
        /// disagreements there add nothing, so revisits do not grow the map
        /// while closer views still add detail. Set it to alpha_threshold
        /// to seed every unexplained pixel.
        pub refill_alpha: f32 = 0.5 => value().range(0.0, 1.0),
        /// Where a new Gaussian's query starts: "embedding" (its pixel's
        /// region embedding projected through the decoder's W, so it
        /// decodes to about that embedding before any step; pixels without
        /// one copy a neighbour's query or start at random) or "random" (a
        /// neighbouring Gaussian's query, else N(0, 1)).
        pub query_init: QueryInit = QueryInit::Embedding => value(),
        /// A pixel without a valid depth (RGB-D sensors leave 5-15 % of
        /// pixels empty: shadows beside edges, dark, shiny or distant
        /// surfaces) is seeded at the median depth of the nearest ring of
        /// pixels around it that has valid ones, up to this many pixels
        /// away. 0 seeds measured depth only, and empty pixels stay holes
        /// in the map. Gaussians seeded from filled-in depth that a later
        /// keyframe sees floating in front of the surface it measured are
        /// removed at the next pruning (prune_interval).
        pub hole_fill_radius: u32 = 8 => value().range(0u32, MAX_HOLE_FILL_RADIUS),
        /// Holes that reach the image's edge (where the depth camera sees
        /// less than the colour camera, as registered Kinect and RealSense
        /// depth does) are filled the same way up to this many pixels
        /// away. Below hole_fill_radius it acts as hole_fill_radius (set
        /// both to 0 to seed measured depth only).
        pub border_fill_radius: u32 = 16 => value().range(0u32, MAX_HOLE_FILL_RADIUS),
    }
}

/// Largest `hole_fill_radius`: wider holes are not one surface.
pub const MAX_HOLE_FILL_RADIUS: u32 = 64;
/// Largest `depth_error`: a rendered depth ten times off the measured one
/// already explains nothing.
pub const MAX_DEPTH_ERROR: f32 = 10.0;
/// Largest `scale_factor`: new Gaussians a hundred seed spacings wide
/// cover the whole view; larger ones only overflow the covariance.
pub const MAX_SCALE_FACTOR: f32 = 100.0;

/// Where a new Gaussian's query starts (the paper leaves it open).
///
/// ```
/// use latentam_core::map::QueryInit;
///
/// let mut config = latentam_core::mapper::MapperConfig::default();
/// config.seeding.query_init = QueryInit::Random; // e.g. an ablation against `Embedding`
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum QueryInit {
    /// From the seeding pixel's region embedding, projected through the
    /// decoder (`crate::latent::projected_queries`), so it decodes to about
    /// that embedding from the start; a pixel without one copies a
    /// neighbouring Gaussian's query, or starts at random.
    #[default]
    Embedding,
    /// A neighbouring Gaussian's query when there is one (in the 26
    /// voxels around), else N(0, 1).
    Random,
}

/// Initial queries by region for the pixels of one keyframe
/// ([`QueryInit::Embedding`]).
///
/// ```
/// use latentam_core::map::{seed_from_frame, GlobalMap, RegionQueries, SeedingConfig};
/// # fn f(frame: &latentam_io::Frame, map: &GlobalMap, labels: &[u16], queries: &[Option<[f32; 32]>]) {
/// // `queries[r]`: region r's embedding projected to a query (`latent::projected_queries`).
/// let (width, height) = (frame.color.width, frame.color.height);
/// let regions = RegionQueries { width, height, labels, queries };
/// let new = seed_from_frame(frame, None, map, &SeedingConfig::default(), 7, Some(&regions));
/// # }
/// ```
#[derive(Clone, Copy, Debug)]
pub struct RegionQueries<'a> {
    /// Label image columns (grid columns for a feature grid).
    pub width: u32,
    /// Label image rows.
    pub height: u32,
    /// Region per label pixel (out of range = none).
    pub labels: &'a [u16],
    /// The query of each region, where it has one.
    pub queries: &'a [Option<[f32; QUERY_DIM]>],
}

impl SeedingConfig {
    /// The pixel stride of seed candidates for a camera of focal length
    /// `focal` pixels: `stride`, or with 0 one candidate per 3.3 mrad
    /// (round(focal / 300)), at least every 2nd pixel.
    ///
    /// ```
    /// use latentam_core::map::SeedingConfig;
    /// let auto = SeedingConfig::default();
    /// assert_eq!(auto.pixel_stride(585.0), 2); // Kinect, 640×480
    /// assert_eq!(auto.pixel_stride(910.0), 3); // RealSense D435, 1280×720
    /// assert_eq!(auto.pixel_stride(1400.0), 5); // 1920×1080
    /// assert_eq!(auto.pixel_stride(120.0), 2); // a 160×120 preview
    /// assert_eq!(SeedingConfig { stride: 4, ..auto }.pixel_stride(910.0), 4);
    /// ```
    pub fn pixel_stride(&self, focal: f64) -> u32 {
        if self.stride > 0 {
            return self.stride;
        }
        let per_3_mrad = (focal / 300.0).round();
        if per_3_mrad.is_finite() {
            per_3_mrad.clamp(2.0, 64.0) as u32
        } else {
            2
        }
    }

    /// The pixels of a `width` × `height` image with focal length `focal`
    /// that are seed candidates: every [`SeedingConfig::pixel_stride`]-th
    /// pixel across and down, at the centre of each stride cell. (An image
    /// narrower than half a stride, one row say, still has its first pixel
    /// as one: it would otherwise seed nothing at all.) Seeding reads what
    /// the map renders only there.
    ///
    /// ```
    /// use latentam_core::map::SeedingConfig;
    /// use latentam_core::splat::PixelGrid;
    /// let grid = SeedingConfig::default().candidate_grid(585.0, 640, 480);
    /// assert_eq!(grid, PixelGrid { stride: 2, start: [1, 1] });
    /// assert_eq!(grid.cells(640, 480), 320 * 240);
    /// ```
    pub fn candidate_grid(&self, focal: f64, width: u32, height: u32) -> PixelGrid {
        let stride = self.pixel_stride(focal);
        let start = |side: u32| (stride / 2).min(side.saturating_sub(1));
        PixelGrid {
            stride,
            start: [start(width), start(height)],
        }
    }
}

impl RegionQueries<'_> {
    /// The query of the region under image pixel `(u, v)` of a `w × h`
    /// image (the label image may have another size).
    fn at(&self, u: u32, v: u32, w: u32, h: u32) -> Option<[f32; QUERY_DIM]> {
        let x = (u as u64 * self.width as u64 / w.max(1) as u64) as usize;
        let y = (v as u64 * self.height as u64 / h.max(1) as u64) as usize;
        let label = *self.labels.get(y * self.width as usize + x)?;
        *self.queries.get(label as usize)?
    }
}

impl Setting for QueryInit {}

/// How much of a keyframe the current map covers: what it renders at the
/// keyframe's pose, at a grid of its pixels (every pixel, or seeding's
/// candidates alone: [`SeedingConfig::candidate_grid`]).
///
/// ```
/// use latentam_core::map::{seed_from_frame, GlobalMap, SeedingConfig, ViewCoverage};
/// use latentam_core::splat::PixelGrid;
/// # fn f(frame: &latentam_io::Frame, map: &GlobalMap, alpha: &[f32], depth: &[f32]) {
/// // What the map renders at the frame's pose: only pixels it does not explain are seeded.
/// let coverage = ViewCoverage { grid: PixelGrid::ALL, alpha, depth, partial: false, complete_within: None, exposure: 1.0 };
/// let new = seed_from_frame(frame, Some(coverage), map, &SeedingConfig::default(), 7, None);
/// println!("{} new Gaussians", new.len());
/// # }
/// ```
#[derive(Clone, Copy, Debug)]
pub struct ViewCoverage<'a> {
    /// The pixels `alpha` and `depth` hold, cell by cell. A seed candidate
    /// off the grid counts as unexplained.
    pub grid: PixelGrid,
    /// Accumulated alpha per cell.
    pub alpha: &'a [f32],
    /// Unnormalised depth `Σ wᵢ zᵢ` (the rasterizer's output) per cell.
    pub depth: &'a [f32],
    /// The render shows only part of the map near the camera (the GPU
    /// window was too small for all of it): a pixel it does not explain
    /// is still explained when its point lies on mapped surface
    /// ([`GlobalMap::is_near_occupied`]), so Gaussians that are paged out
    /// are not seeded again beside themselves.
    pub partial: bool,
    /// The render holds every Gaussian within this radius (metres) of this
    /// centre, and possibly not those beyond (the window's extent when
    /// Gaussians are paged out): pixels whose points lie beyond are
    /// treated as under `partial`. `None`: no limit.
    pub complete_within: Option<(DVec3, f64)>,
    /// The frame's gain over the map (`relative_exposure`): new Gaussians
    /// take the frame's colour divided by it, in the map's brightness.
    pub exposure: f32,
}

impl ViewCoverage<'_> {
    /// Alpha and unnormalised depth at pixel `(u, v)` of a `width`-wide
    /// image; `None` off the grid.
    fn at(&self, u: u32, v: u32, width: u32) -> Option<(f32, f32)> {
        let k = self.grid.cell(u, v, width)?;
        Some((*self.alpha.get(k)?, *self.depth.get(k)?))
    }
}

/// An initial query: a neighbour's (so a surface keeps one latent code
/// while it grows), else N(0, 1) from the voxel and seed. Never all-zero:
/// zero queries make the decoder's normalisation degenerate (‖qW‖ = 0).
fn initial_query(key: VoxelKey, map: &GlobalMap, seed: u64) -> [f32; QUERY_DIM] {
    if let Some(g) = key.neighbourhood().find_map(|n| map.get(n)) {
        if g.query.iter().any(|&q| q != 0.0) {
            return g.query;
        }
    }
    let mut rng = SplitMix(
        seed ^ (key.x as u32 as u64)
            ^ ((key.y as u32 as u64) << 21)
            ^ ((key.z as u32 as u64) << 42),
    );
    std::array::from_fn(|_| rng.normal())
}

/// The median of the valid depths on the nearest square ring around pixel
/// `(u, v)` (Chebyshev distance 1 to `radius`) that has any.
/// `ring` is scratch space, reused across calls.
fn borrowed_depth(
    depth: &DepthImage,
    u: u32,
    v: u32,
    radius: u32,
    ring: &mut Vec<f32>,
) -> Option<f32> {
    let (w, h) = (depth.width as i64, depth.height as i64);
    let (u, v) = (u as i64, v as i64);
    for r in 1..=radius as i64 {
        ring.clear();
        let mut take = |x: i64, y: i64| {
            if (0..w).contains(&x) && (0..h).contains(&y) {
                if let Some(z) = depth.metres((y * w + x) as usize) {
                    ring.push(z);
                }
            }
        };
        square_ring(u, v, r, &mut take);
        if !ring.is_empty() {
            let mid = ring.len() / 2;
            return Some(*ring.select_nth_unstable_by(mid, f32::total_cmp).1);
        }
    }
    None
}

/// Calls `take(x, y)` for each pixel at Chebyshev distance `r` from
/// `(u, v)`, once each.
fn square_ring(u: i64, v: i64, r: i64, mut take: impl FnMut(i64, i64)) {
    for d in -r..r {
        take(u + d, v - r);
        take(u + r, v + d);
        take(u - d, v + r);
        take(u - r, v - d);
    }
}

/// Per pixel: whether it has no valid depth and is connected to the
/// image's edge through pixels that have none either (4-neighbours).
fn holes_reaching_the_edge(depth: &DepthImage) -> Vec<bool> {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let mut reached = vec![false; w * h];
    let mut stack: Vec<usize> = (0..w)
        .flat_map(|x| [x, (h.max(1) - 1) * w + x])
        .chain((0..h).flat_map(|y| [y * w, y * w + w.max(1) - 1]))
        .filter(|&i| i < w * h)
        .collect();
    while let Some(i) = stack.pop() {
        if reached[i] || depth.metres(i).is_some() {
            continue;
        }
        reached[i] = true;
        let (x, y) = (i % w, i / w);
        if x > 0 {
            stack.push(i - 1);
        }
        if x + 1 < w {
            stack.push(i + 1);
        }
        if y > 0 {
            stack.push(i - w);
        }
        if y + 1 < h {
            stack.push(i + w);
        }
    }
    reached
}

/// Gaussians to add for `frame`: one per free voxel hit by a candidate
/// pixel with valid depth that the map does not explain (`rendered` says
/// what it shows there; without it every candidate is unexplained). With
/// `queries`, a pixel in a region that has one starts from its region's
/// query.
pub fn seed_from_frame(
    frame: &Frame,
    rendered: Option<ViewCoverage<'_>>,
    map: &GlobalMap,
    config: &SeedingConfig,
    seed: u64,
    queries: Option<&RegionQueries<'_>>,
) -> Vec<Gaussian> {
    let k = frame.intrinsics;
    let (w, h) = (frame.color.width, frame.color.height);
    let rotation = frame.pose.rotation;
    let translation = frame.pose.translation;
    let focal = 0.5 * (k.fx + k.fy);
    let voxel = map.voxel_size();
    let opacity = config.opacity.clamp(1e-4, 1.0 - 1e-4);
    let opacity_logit = (opacity / (1.0 - opacity)).ln();
    let grid = config.candidate_grid(focal, w, h);
    let stride = grid.stride;
    if let Some(r) = &rendered {
        // A render of other pixels would leave candidates unexplained.
        debug_assert!(
            (r.grid == PixelGrid::ALL || r.grid == grid)
                && r.alpha.len() as u64 == r.grid.cells(w, h)
                && r.depth.len() == r.alpha.len(),
            "coverage of {:?} ({} cells) for candidates {grid:?} of a {w}x{h} image",
            r.grid,
            r.alpha.len()
        );
    }
    let mut taken: HashSet<VoxelKey> = HashSet::new();
    let mut ring = Vec::new();
    let border_holes = (config.border_fill_radius > config.hole_fill_radius)
        .then(|| holes_reaching_the_edge(&frame.depth));
    let mut out = Vec::new();
    for v in (grid.start[1]..h).step_by(stride as usize) {
        for u in (grid.start[0]..w).step_by(stride as usize) {
            let i = (v * w + u) as usize;
            let Some(z) = frame
                .depth
                .metres(i)
                .or_else(|| borrowed_depth(&frame.depth, u, v, config.hole_fill_radius, &mut ring))
                .or_else(|| {
                    let border = border_holes.as_ref()?;
                    let radius = config.border_fill_radius;
                    border[i].then(|| borrowed_depth(&frame.depth, u, v, radius, &mut ring))?
                })
            else {
                continue;
            };
            if z > config.max_depth {
                continue;
            }
            let covered = rendered.and_then(|r| r.at(u, v, w));
            if let Some((a, depth)) = covered {
                let explained = a >= config.alpha_threshold
                    && ((depth / a.max(1e-6)) - z).abs() <= config.depth_error * z;
                if explained {
                    continue;
                }
            }
            let z = z as f64;
            let cam = DVec3::new(
                (u as f64 - k.cx) / k.fx * z,
                (v as f64 - k.cy) / k.fy * z,
                z,
            );
            let p = rotation * cam + translation;
            let Some(key) = map.key_of(p) else { continue };
            let beyond_render = rendered.is_some_and(|r| {
                r.partial
                    || r.complete_within
                        .is_some_and(|(centre, radius)| p.distance(centre) > radius)
            });
            if beyond_render && map.is_near_occupied(p) {
                continue;
            }
            // Surface already seeded at this seed spacing (or finer) is not
            // seeded again unless the render has a hole there; closer views
            // (finer spacing) still refine coarser surface.
            let spacing = stride as f64 * z / focal;
            let filled = covered.is_some_and(|(a, _)| a >= config.refill_alpha);
            if filled && map.is_mapped_within(p, spacing) {
                continue;
            }
            if map.contains(key) || !taken.insert(key) {
                continue;
            }
            let sigma = (config.scale_factor as f64 * stride as f64 * z / focal).max(0.5 * voxel);
            let rgb = frame.color.rgb(u, v);
            let gain = rendered.map_or(1.0, |r| r.exposure);
            out.push(Gaussian {
                mean: p.as_vec3().to_array(),
                log_scale: [sigma.ln() as f32; 3],
                quat: [1.0, 0.0, 0.0, 0.0],
                color: rgb.map(|c| c as f32 / 255.0 / gain),
                opacity_logit,
                query: queries
                    .and_then(|q| q.at(u, v, w, h))
                    .unwrap_or_else(|| initial_query(key, map, seed)),
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentam_io::DepthData;

    /// A floor seen at a slant: inverse depth rises by `slope` per row
    /// (the plane's depths in metres, 0 where masked).
    fn slanted(w: u32, h: u32, slope: f32, missing: impl Fn(u32, u32) -> bool) -> DepthImage {
        let values = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if missing(x, y) {
                    0.0
                } else {
                    1.0 / (0.25 + slope * y as f32 + 0.001 * x as f32)
                }
            })
            .collect();
        DepthImage {
            width: w,
            height: h,
            data: DepthData::Metres(values),
        }
    }

    #[test]
    fn only_holes_that_reach_the_edge_are_border_holes() {
        // A band along the right edge and a hole in the middle.
        let depth = slanted(40, 30, 0.01, |x, y| {
            x >= 34 || (15..18).contains(&x) && (10..13).contains(&y)
        });
        let border = holes_reaching_the_edge(&depth);
        for (i, &b) in border.iter().enumerate() {
            let (x, y) = (i % 40, i / 40);
            assert_eq!(b, x >= 34, "pixel ({x}, {y})");
        }
    }
}
