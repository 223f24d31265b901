//! CPU ray casting of the demo world into colour, depth, class and
//! instance images.

use glam::{Mat3, Vec3};

use super::geometry::Hit;
use super::layout::{Scene, Surface};

/// One rendered view.
pub struct View {
    /// Packed RGB.
    pub color: Vec<u8>,
    /// Depth along the optical axis in millimetres, 0 where nothing is hit.
    pub depth_mm: Vec<u16>,
    /// Class id per pixel (0 = nothing).
    pub class: Vec<u16>,
    /// Instance id per pixel (0 = nothing).
    pub instance: Vec<u16>,
}

/// Pinhole intrinsics `[fx, fy, cx, cy]` for a `width × height` image: a
/// 67° horizontal field of view, principal point at the image centre
/// (OpenCV pixel centres).
pub fn intrinsics(width: u32, height: u32) -> [f64; 4] {
    let f = 0.75 * width as f64;
    [
        f,
        f,
        (width as f64 - 1.0) / 2.0,
        (height as f64 - 1.0) / 2.0,
    ]
}

const LIGHT: Vec3 = Vec3::new(0.35, 0.55, 0.76);
const MAX_DEPTH_MM: f32 = 65_000.0;

/// The surfaces' indices with the distance from `position` to their
/// bounding boxes, nearest first.
fn surfaces_by_distance(scene: &Scene, position: Vec3) -> Vec<(f32, usize)> {
    let mut order: Vec<(f32, usize)> = scene
        .surfaces
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let (min, max) = s.shape.bounds();
            (position.clamp(min, max).distance(position), i)
        })
        .collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    order
}

/// The surface a ray from `position` along `dir` meets first: the least
/// ray parameter, and among equal ones the surface listed first, as a
/// scan of every surface in order finds it. Surfaces are tried nearest
/// box first (`by_distance`), and the scan stops at the first box farther
/// than the hit in hand, so a view of a large building costs the surfaces
/// near the camera, not all of them. A hit is never nearer than its box;
/// the margin covers rounding.
fn nearest_hit<'s>(
    scene: &'s Scene,
    by_distance: &[(f32, usize)],
    position: Vec3,
    dir: Vec3,
) -> Option<(Hit, &'s Surface)> {
    let length = dir.length();
    let mut best: Option<(Hit, usize)> = None;
    for &(box_distance, i) in by_distance {
        if let Some((b, _)) = best {
            let hit_distance = b.t * length;
            if box_distance > hit_distance * (1.0 + 1e-4) + 1e-4 {
                break;
            }
        }
        if let Some(h) = scene.surfaces[i].shape.intersect(position, dir, 1e-3) {
            if best.is_none_or(|(b, j)| h.t < b.t || (h.t == b.t && i < j)) {
                best = Some((h, i));
            }
        }
    }
    best.map(|(h, i)| (h, &scene.surfaces[i]))
}

/// Renders the scene from a camera-to-world `rotation` and `position`.
pub fn render(scene: &Scene, rotation: Mat3, position: Vec3, width: u32, height: u32) -> View {
    let [fx, fy, cx, cy] = intrinsics(width, height).map(|v| v as f32);
    let n = (width * height) as usize;
    let mut view = View {
        color: vec![0; n * 3],
        depth_mm: vec![0; n],
        class: vec![0; n],
        instance: vec![0; n],
    };
    let light = LIGHT.normalize();
    let by_distance = &surfaces_by_distance(scene, position);
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(8);
    let rows_per = (height as usize).div_ceil(threads);
    let row_len = width as usize;
    std::thread::scope(|scope| {
        let chunks = view
            .color
            .chunks_mut(rows_per * row_len * 3)
            .zip(view.depth_mm.chunks_mut(rows_per * row_len))
            .zip(view.class.chunks_mut(rows_per * row_len))
            .zip(view.instance.chunks_mut(rows_per * row_len))
            .enumerate();
        for (c, (((color, depth), class), instance)) in chunks {
            scope.spawn(move || {
                for (k, d) in depth.iter_mut().enumerate() {
                    let v = (c * rows_per + k / row_len) as f32;
                    let u = (k % row_len) as f32;
                    // z = 1 in the camera frame, so the ray parameter is depth.
                    let dir = rotation * Vec3::new((u - cx) / fx, (v - cy) / fy, 1.0);
                    let Some((hit, surface)) = nearest_hit(scene, by_distance, position, dir)
                    else {
                        continue;
                    };
                    let mm = (hit.t * 1000.0).round();
                    if (1.0..=MAX_DEPTH_MM).contains(&mm) {
                        *d = mm as u16;
                    }
                    let shade = 0.45 + 0.55 * hit.normal.dot(light).abs();
                    let rgb = surface.texture.colour(hit.uv) * shade;
                    for ch in 0..3 {
                        color[k * 3 + ch] = (rgb[ch] * 255.0).round().clamp(0.0, 255.0) as u8;
                    }
                    class[k] = surface.class;
                    instance[k] = surface.instance;
                }
            });
        }
    });
    view
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::building::building;
    use crate::trajectory::CameraPath;

    /// The first surface by a scan of every one, in order.
    fn scan_every_surface(scene: &Scene, position: Vec3, dir: Vec3) -> Option<(Hit, usize)> {
        let mut best: Option<(Hit, usize)> = None;
        for (i, s) in scene.surfaces.iter().enumerate() {
            if let Some(h) = s.shape.intersect(position, dir, 1e-3) {
                if best.is_none_or(|(b, _)| h.t < b.t) {
                    best = Some((h, i));
                }
            }
        }
        best
    }

    #[test]
    fn rays_tried_nearest_box_first_find_what_a_scan_of_every_surface_finds() {
        for (scene, path) in [(Scene::two_rooms(), CameraPath::demo()), building(12)] {
            let frames = 40;
            for i in 0..frames {
                let (rotation, position) = path.pose(i, frames, 2);
                let order = surfaces_by_distance(&scene, position);
                let [fx, fy, cx, cy] = intrinsics(48, 36).map(|v| v as f32);
                for v in 0..36 {
                    for u in 0..48 {
                        let dir =
                            rotation * Vec3::new((u as f32 - cx) / fx, (v as f32 - cy) / fy, 1.0);
                        let got = nearest_hit(&scene, &order, position, dir)
                            .map(|(h, s)| (h.t, s as *const Surface));
                        let want = scan_every_surface(&scene, position, dir)
                            .map(|(h, i)| (h.t, &scene.surfaces[i] as *const Surface));
                        assert_eq!(got, want, "frame {i}, pixel ({u}, {v})");
                    }
                }
            }
        }
    }
}
