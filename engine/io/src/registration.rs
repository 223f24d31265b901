//! Registering a depth image to the colour camera: RGB-D sensors whose
//! depth and colour come from two lenses (raw Kinect streams, datasets
//! recorded without the driver's registration) give a colour pixel and
//! the depth pixel of the same coordinates that look at different
//! surfaces, a few pixels apart and more at silhouettes. The mapper reads
//! both images through one camera, so such depth must first be re-projected
//! into the colour camera: while a log is read (from its own camera infos
//! and `/tf_static`, see `FrameAssembler`) or by `latentam convert`.

use glam::{DMat3, DQuat, DVec3};

use crate::Pose;

/// The depth camera as seen from the colour camera, and both lenses.
///
/// A point `x` in the depth camera's optical frame (x right, y down, z
/// forward, metres) lies at `rotation * x + translation` in the colour
/// camera's.
///
/// ```
/// use glam::{DQuat, DVec3};
/// use latentam_io::DepthRegistration;
///
/// // Colour lens 10 % shorter, 2.5 cm to the right of the depth lens.
/// let reg = DepthRegistration {
///     depth: [585.0, 585.0, 320.0, 240.0],
///     colour: [526.5, 526.5, 320.0, 240.0],
///     rotation: DQuat::IDENTITY,
///     translation: DVec3::new(-0.025, 0.0, 0.0),
/// };
/// let depth_mm = vec![2000u16; 640 * 480];
/// let registered = reg.register(640, 480, &depth_mm, 1000.0, 640, 480);
/// assert_eq!(registered[240 * 640 + 320], 2000);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthRegistration {
    /// Depth camera `[fx, fy, cx, cy]` in pixels.
    pub depth: [f64; 4],
    /// Colour camera `[fx, fy, cx, cy]` in pixels.
    pub colour: [f64; 4],
    /// Rotation from the depth camera's frame to the colour camera's.
    pub rotation: DQuat,
    /// The depth camera's origin in the colour camera's frame (metres).
    pub translation: DVec3,
}

impl DepthRegistration {
    /// Depth `values` (`width × height`, `units_per_metre`, 0 = no
    /// measurement) re-projected into a `out_width × out_height` colour image, in the
    /// same unit, as the colour camera's z. Each depth pixel covers the
    /// colour pixels its footprint lands on, and the nearest surface wins,
    /// so a pixel seen by colour but hidden from depth stays 0 rather than
    /// taking the occluder's background.
    pub fn register(
        &self,
        width: usize,
        height: usize,
        values: &[u16],
        units_per_metre: f64,
        out_width: usize,
        out_height: usize,
    ) -> Vec<u16> {
        let [dfx, dfy, dcx, dcy] = self.depth;
        let [cfx, cfy, ccx, ccy] = self.colour;
        let r = DMat3::from_quat(self.rotation.normalize());
        let t = self.translation * units_per_metre;
        let mut out = vec![0u16; out_width * out_height];
        for v in 0..height {
            for u in 0..width {
                let d = values[v * width + u];
                if d == 0 {
                    continue;
                }
                let z = d as f64;
                let x = DVec3::new((u as f64 - dcx) / dfx * z, (v as f64 - dcy) / dfy * z, z);
                let p = r * x + t;
                if p.z <= 0.0 {
                    continue;
                }
                // The depth pixel's footprint: its centre ± half its size
                // at this distance, in colour pixels.
                let (cu, cv) = (cfx * p.x / p.z + ccx, cfy * p.y / p.z + ccy);
                if !(cu.is_finite() && cv.is_finite()) {
                    continue;
                }
                let (hu, hv) = (0.5 * cfx / dfx * z / p.z, 0.5 * cfy / dfy * z / p.z);
                // Pixel i's centre is at coordinate i: the footprint covers
                // the centres inside it, and at least the pixel holding cu.
                let span = |c: f64, h: f64, n: usize| {
                    let lo = (c - h).ceil().min(c.round()).max(0.0);
                    let hi = (c + h).floor().max(c.round()).min(n as f64 - 1.0);
                    if hi < lo {
                        0..0
                    } else {
                        lo as usize..hi as usize + 1
                    }
                };
                let zc = p.z.round().clamp(1.0, u16::MAX as f64) as u16;
                for row in span(cv, hv, out_height) {
                    for col in span(cu, hu, out_width) {
                        let o = &mut out[row * out_width + col];
                        if *o == 0 || zc < *o {
                            *o = zc;
                        }
                    }
                }
            }
        }
        out
    }

    /// The colour camera's pose, given the depth camera's (both camera to
    /// world): `world ← depth ← colour`.
    pub fn colour_pose(&self, depth_pose: &Pose) -> Pose {
        let inv = self.rotation.normalize().inverse();
        let to_colour_origin = -(inv * self.translation);
        Pose {
            translation: depth_pose.translation + depth_pose.rotation * to_colour_origin,
            rotation: (depth_pose.rotation * inv).normalize(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reg(rotation: DQuat, translation: DVec3) -> DepthRegistration {
        DepthRegistration {
            depth: [585.0, 580.0, 321.0, 238.0],
            colour: [529.0, 531.0, 318.5, 241.0],
            rotation,
            translation,
        }
    }

    /// A surface point seen by both cameras: depth registered into the
    /// colour camera must give, at the colour pixel the point projects to,
    /// the point's colour-camera z (within the footprint's rounding).
    #[test]
    fn registered_depth_is_where_the_colour_camera_sees_the_surface() {
        let rotation = DQuat::from_euler(glam::EulerRot::XYZ, 0.01, -0.02, 0.015);
        let r = reg(rotation, DVec3::new(-0.025, 0.004, 0.002));
        // A slanted plane: z = 1.5 + 0.8 x_n in the depth camera, so a
        // pixel off changes the depth by about 2 mm.
        let (w, h) = (640, 480);
        let mut values = vec![0u16; w * h];
        for v in 0..h {
            for u in 0..w {
                let xn = (u as f64 - 321.0) / 585.0;
                values[v * w + u] = ((1.5 + 0.8 * xn) * 1000.0).round() as u16;
            }
        }
        let out = r.register(w, h, &values, 1000.0, w, h);
        let rot = DMat3::from_quat(rotation);
        let mut checked = 0;
        for v in (8..h - 8).step_by(3) {
            for u in (8..w - 8).step_by(3) {
                let z = values[v * w + u] as f64 / 1000.0;
                let x = DVec3::new(
                    (u as f64 - 321.0) / 585.0 * z,
                    (v as f64 - 238.0) / 580.0 * z,
                    z,
                );
                let p = rot * x + r.translation;
                let (cu, cv) = (529.0 * p.x / p.z + 318.5, 531.0 * p.y / p.z + 241.0);
                let (iu, iv) = (cu.round() as usize, cv.round() as usize);
                if iu >= w || iv >= h {
                    continue;
                }
                let got = out[iv * w + iu] as f64 / 1000.0;
                assert!((got - p.z).abs() < 0.005, "({u}, {v}): {got} vs {}", p.z);
                checked += 1;
            }
        }
        assert!(checked > 1000, "{checked}");
    }

    /// A near object in front of a far wall: where both land on one colour
    /// pixel, the near one wins; no measurement stays no measurement.
    #[test]
    fn the_nearest_surface_wins_and_holes_stay_holes() {
        let r = reg(DQuat::IDENTITY, DVec3::new(-0.05, 0.0, 0.0));
        let (w, h) = (640, 480);
        let mut values = vec![3000u16; w * h];
        for v in 200..280 {
            for u in 300..340 {
                values[v * w + u] = 500;
            }
        }
        for v in 0..h {
            values[v * w + 10] = 0;
        }
        let out = r.register(w, h, &values, 1000.0, w, h);
        // The object's centre: colour column of a 0.5 m point at depth
        // column 320.
        let cu = (529.0f64 * ((320.0 - 321.0) / 585.0 * 0.5 - 0.05) / 0.5 + 318.5).round() as usize;
        let cv = (531.0f64 * ((240.0 - 238.0) / 580.0) + 241.0).round() as usize;
        assert_eq!(out[cv * w + cu], 500);
        // The wall far from the object keeps its depth.
        assert_eq!(out[100 * w + 500], 3000);
        assert!(out.iter().all(|&d| d == 0 || d == 500 || d == 3000));
        // Only the empty column and what lies outside the depth camera's
        // view are empty; the 5 cm shift hides a strip of wall behind the
        // object from the depth camera, which stays empty too.
        let empty = out.iter().filter(|&&d| d == 0).count();
        assert!(empty < w * h / 5, "{empty}");
    }

    /// The colour camera's pose composes the depth camera's with the
    /// offset: a point at the colour camera's origin is at its pose's
    /// translation in the world.
    #[test]
    fn colour_pose_is_the_depth_pose_moved_by_the_offset() {
        let rotation = DQuat::from_euler(glam::EulerRot::XYZ, 0.1, 0.2, -0.3);
        let r = reg(rotation, DVec3::new(-0.025, 0.01, 0.003));
        let depth_pose = Pose {
            translation: DVec3::new(1.0, -2.0, 0.5),
            rotation: DQuat::from_euler(glam::EulerRot::XYZ, -0.4, 0.3, 1.2),
        };
        let c = r.colour_pose(&depth_pose);
        // A world point, through depth then colour coordinates, must
        // match the colour pose's own view of it.
        let world = DVec3::new(0.3, 0.7, 2.0);
        let in_depth = depth_pose.rotation.inverse() * (world - depth_pose.translation);
        let in_colour = rotation * in_depth + r.translation;
        let via_pose = c.rotation.inverse() * (world - c.translation);
        assert!(
            (in_colour - via_pose).length() < 1e-12,
            "{in_colour} vs {via_pose}"
        );
    }
}
