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
                    let mut best: Option<(Hit, &Surface)> = None;
                    for s in &scene.surfaces {
                        if let Some(h) = s.shape.intersect(position, dir, 1e-3) {
                            if best.is_none_or(|(b, _)| h.t < b.t) {
                                best = Some((h, s));
                            }
                        }
                    }
                    let Some((hit, surface)) = best else { continue };
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
