//! The seeding part of the mapper: from a keyframe and what the map
//! already explains at its pose (the GPU window rendered there), new
//! Gaussians where it explains nothing (paper §III-A), and the guesses
//! among them, Gaussians seeded where the keyframe measured no depth,
//! until a later keyframe measures their surface or sees them float in
//! front of it.

use glam::DVec3;

use crate::map::{
    relative_exposure, seed_from_frame, Gaussian, GlobalMap, KeySet, LocalWindow, RegionQueries,
    SeedingConfig, ViewCoverage, VoxelKey,
};
use crate::mapper::history::KeyframeRecord;
use crate::splat::{PixelGrid, Rasterizer};
use latentam_base::Result;
use latentam_gpu::Buffer;
use latentam_io::Frame;

#[cfg(test)]
mod tests;

/// The window rendered at a keyframe's pose, at seeding's candidate
/// pixels: what the map explains there. Only those pixels are read back
/// (a quarter of the image at a stride of 2, a ninth at 3).
pub(crate) struct Coverage {
    /// The pixels rendered, cell by cell.
    pub grid: PixelGrid,
    /// Accumulated alpha per cell.
    pub alpha: Vec<f32>,
    /// Unnormalised depth per cell, as the rasterizer gives it.
    pub depth: Vec<f32>,
    /// Colour and depth per cell.
    pub rgbd: Vec<[f32; 4]>,
    /// The decoder's W as it stood when the window was rendered, when
    /// asked for: read back with the render, so that projecting region
    /// embeddings needs no wait of its own.
    pub w: Option<Vec<f32>>,
}

impl Coverage {
    /// Renders `window` from the keyframe's camera at the pixels of
    /// `grid`, reading `w` back beside it; `None` while the window is
    /// empty.
    pub(crate) fn render(
        raster: &mut Rasterizer,
        window: &LocalWindow,
        record: &KeyframeRecord,
        grid: PixelGrid,
        w: Option<&Buffer>,
    ) -> Result<Option<Coverage>> {
        if window.is_empty() {
            return Ok(None);
        }
        // Coverage needs alpha and depth; exposure colour.
        let count = window.len() as u64;
        let render = raster.render_alpha_rgbd(window.params(), count, &record.camera, grid, w)?;
        let depth = render.rgbd.iter().map(|p| p[3]).collect();
        Ok(Some(Coverage {
            grid,
            alpha: render.alpha,
            depth,
            rgbd: render.rgbd,
            w: render.also,
        }))
    }

    /// The keyframe's exposure against the map where the map renders its
    /// surface (within `depth_error` of the depth the frame measured), at
    /// the rendered pixels; `None` where too little of the map is in view
    /// to tell.
    pub(crate) fn exposure(
        &self,
        frame: &Frame,
        record: &KeyframeRecord,
        depth_error: f32,
    ) -> Option<f32> {
        let width = record.camera.width;
        let pixel = |k: usize| {
            self.grid
                .pixel(k, width)
                .map(|(u, v)| (v * width + u) as usize)
        };
        let pixels: Vec<usize> = (0..self.alpha.len()).filter_map(pixel).collect();
        let observed: Vec<u8> = pixels
            .iter()
            .flat_map(|&i| [0, 1, 2].map(|c| record.rgb.get(3 * i + c).copied().unwrap_or(0)))
            .collect();
        let measured = |k: usize| frame.depth.metres(*pixels.get(k)?);
        relative_exposure(&observed, &self.rgbd, &self.alpha, measured, depth_error)
    }
}

/// How much of the map a [`Coverage`] render shows: the window may hold
/// only the part of the map near the camera.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Extent {
    /// Gaussians that may be in view were left out of the window.
    pub partial: bool,
    /// The window holds every Gaussian within this radius of this centre.
    pub complete_within: Option<(DVec3, f64)>,
}

/// New Gaussians from keyframes, and the guesses among the map's.
pub(crate) struct Seeder {
    cfg: SeedingConfig,
    /// Gaussians seeded where their keyframe measured no depth (holes
    /// filled from their neighbours), until a later keyframe measures
    /// their surface.
    guesses: KeySet,
    /// Guesses a later keyframe saw in front of the surface it measured:
    /// removed at the next pruning.
    superseded: KeySet,
}

impl Seeder {
    /// A seeder with no guesses.
    pub(crate) fn new(cfg: SeedingConfig) -> Self {
        Seeder {
            cfg,
            guesses: KeySet::default(),
            superseded: KeySet::default(),
        }
    }

    /// New Gaussians for `frame` where `coverage` (the map rendered at its
    /// pose, seen to `extent`; `None`: nothing rendered) does not explain
    /// it, in the map's brightness (`exposure` is the frame's gain over
    /// it), starting from `queries` where a region has one.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn seeds(
        &self,
        frame: &Frame,
        coverage: Option<&Coverage>,
        extent: Extent,
        exposure: f32,
        global: &GlobalMap,
        seed: u64,
        queries: Option<&RegionQueries<'_>>,
    ) -> Vec<Gaussian> {
        let mut seeds = seed_from_frame(
            frame,
            coverage.map(|c| ViewCoverage {
                grid: c.grid,
                alpha: &c.alpha,
                depth: &c.depth,
                partial: extent.partial,
                complete_within: extent.complete_within,
                exposure,
            }),
            global,
            &self.cfg,
            seed,
            queries,
        );
        if coverage.is_none() {
            // Without a render seeding took the colours as they are.
            for g in &mut seeds {
                g.color = g.color.map(|c| c / exposure);
            }
        }
        seeds
    }

    /// The pixels of `frame` seeding looks at, where the map's render is
    /// all it reads.
    pub(crate) fn candidate_grid(&self, frame: &Frame) -> PixelGrid {
        let k = frame.intrinsics;
        let (w, h) = (frame.color.width, frame.color.height);
        self.cfg.candidate_grid(0.5 * (k.fx + k.fy), w, h)
    }

    /// Guesses `frame` measures: kept where its depth agrees, marked for
    /// removal where they float in front of the surface it measured.
    pub(crate) fn check_guesses(&mut self, frame: &Frame, global: &GlobalMap) {
        let tolerance = self.cfg.depth_error as f64;
        let superseded = &mut self.superseded;
        self.guesses.retain(|&key| {
            let Some(g) = global.get(key) else {
                // Out of sight on disk: still a guess, checked once the
                // camera is back; otherwise pruned away.
                return global.is_spilled(key);
            };
            let Some((z, Some(measured))) = measured_at(frame, g.mean) else {
                return true;
            };
            let measured = measured as f64;
            if z < measured * (1.0 - tolerance) {
                superseded.insert(key);
                false
            } else {
                // On the measured surface: no longer a guess. Behind it:
                // hidden, so nothing says it is wrong.
                z > measured * (1.0 + tolerance)
            }
        });
    }

    /// Inserts `seeds` into the global map, nearest the camera first
    /// (those whose voxel is taken are dropped); those seeded where the
    /// keyframe measured no depth are guesses. Returns their keys.
    pub(crate) fn insert(
        &mut self,
        frame: &Frame,
        seeds: Vec<Gaussian>,
        global: &mut GlobalMap,
    ) -> Vec<VoxelKey> {
        let centre = frame.pose.translation;
        let dist = |m: [f32; 3]| DVec3::from(m.map(f64::from)).distance_squared(centre);
        // Nearest first, ties in seeding's order: the distances computed
        // once and sorted with their indices, not the Gaussians (184
        // bytes each) with a distance computed at every comparison.
        let mut order: Vec<(f64, u32)> = seeds
            .iter()
            .enumerate()
            .map(|(i, g)| (dist(g.mean), i as u32))
            .collect();
        order.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut keys = Vec::with_capacity(seeds.len());
        for g in order.into_iter().map(|(_, i)| seeds[i as usize]) {
            let guessed = matches!(measured_at(frame, g.mean), Some((_, None)));
            if let Some(key) = global.insert(g) {
                if guessed {
                    self.guesses.insert(key);
                }
                keys.push(key);
            }
        }
        keys
    }

    /// The superseded guesses, which pruning removes; the set is left
    /// empty.
    pub(crate) fn take_superseded(&mut self) -> KeySet {
        std::mem::take(&mut self.superseded)
    }

    /// Whether the Gaussian at `key` is a guess no keyframe measured yet.
    pub(crate) fn is_guess(&self, key: &VoxelKey) -> bool {
        self.guesses.contains(key)
    }

    /// Whether the Gaussian at `key` is a superseded guess.
    pub(crate) fn is_superseded(&self, key: &VoxelKey) -> bool {
        self.superseded.contains(key)
    }

    /// How many of the map's Gaussians are guesses.
    #[cfg(test)]
    pub(crate) fn guesses(&self) -> usize {
        self.guesses.len()
    }

    /// Marks `key` as a guess (a loaded state's).
    pub(crate) fn restore_guess(&mut self, key: VoxelKey) {
        self.guesses.insert(key);
    }

    /// Marks `key` as a superseded guess (a loaded state's).
    pub(crate) fn restore_superseded(&mut self, key: VoxelKey) {
        self.superseded.insert(key);
    }
}

/// The depth of `mean` in `frame`'s camera and what the frame measured at
/// the pixel it projects to (`None` there: no valid depth); `None` outside
/// the image or behind the camera.
fn measured_at(frame: &Frame, mean: [f32; 3]) -> Option<(f64, Option<f32>)> {
    let p =
        frame.pose.rotation.inverse() * (DVec3::from(mean.map(f64::from)) - frame.pose.translation);
    if p.z <= 1e-6 {
        return None;
    }
    let k = frame.intrinsics;
    let u = (k.fx * p.x / p.z + k.cx).round();
    let v = (k.fy * p.y / p.z + k.cy).round();
    let (w, h) = (frame.depth.width as f64, frame.depth.height as f64);
    if !(0.0..w).contains(&u) || !(0.0..h).contains(&v) {
        return None;
    }
    Some((
        p.z,
        frame.depth.metres(v as usize * w as usize + u as usize),
    ))
}
