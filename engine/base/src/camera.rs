//! Pinhole cameras as the rasterizer sees them.

use glam::{DAffine3, DVec3};

/// Guard band: the projection's Jacobian clamps the view direction to the
/// field of view widened by this fraction of tan(fov/2), so Gaussians far
/// outside the image do not get huge 2-D footprints.
pub const GUARD_BAND: f64 = 0.3;

/// A pinhole view: pose, intrinsics, image size and depth range.
///
/// Axes follow OpenCV: x right, y down, z forward. Pixel `(u, v)` (column,
/// row) samples the image plane at `(u, v)`: the centre of the top-left pixel
/// is the origin, which is how OpenCV-style intrinsics (TUM, Replica,
/// 7-Scenes, ROS `CameraInfo`) state `cx`, `cy`.
///
/// ```
/// use latentam_base::Camera;
/// let cam = Camera::looking_at(
///     glam::DVec3::new(0.0, 0.0, -2.0), glam::DVec3::ZERO, glam::DVec3::NEG_Y,
///     320, 240, 300.0);
/// assert_eq!(cam.width, 320);
/// assert!((cam.cx - 159.5).abs() < 1e-12);
/// // `up` points up in the image: a point above the target projects above
/// // the image centre (smaller row).
/// let p = cam.world_to_cam().transform_point3(glam::DVec3::new(0.0, -0.5, 0.0));
/// assert!(cam.fy * p.y / p.z + cam.cy < cam.cy);
/// // The world frame itself, OpenCV axes:
/// assert_eq!(Camera::at_origin(8, 6).cam_to_world, glam::DAffine3::IDENTITY);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Camera-to-world rigid transform.
    pub cam_to_world: DAffine3,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels (pixel-centre convention above).
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Gaussians whose centre is nearer than this (camera z, metres) are not
    /// drawn.
    pub near: f64,
    /// Gaussians whose centre is farther than this are not drawn.
    pub far: f64,
}

impl Camera {
    /// Default near plane, metres.
    pub const DEFAULT_NEAR: f64 = 0.01;
    /// Default far plane, metres.
    pub const DEFAULT_FAR: f64 = 100.0;

    /// A camera at `eye` looking at `target`, `up` pointing up in the image,
    /// with focal length `focal` and the principal point at the image centre.
    pub fn looking_at(
        eye: DVec3,
        target: DVec3,
        up: DVec3,
        width: u32,
        height: u32,
        focal: f64,
    ) -> Self {
        let z = (target - eye).normalize();
        // Right-handed with y down: x = y × z and y = -up (made orthogonal),
        // so x = z × up.
        let x = z.cross(up).normalize();
        let y = z.cross(x);
        Self {
            cam_to_world: DAffine3::from_cols(x, y, z, eye),
            fx: focal,
            fy: focal,
            cx: (width as f64 - 1.0) / 2.0,
            cy: (height as f64 - 1.0) / 2.0,
            width,
            height,
            near: Self::DEFAULT_NEAR,
            far: Self::DEFAULT_FAR,
        }
    }

    /// A camera whose frame is the world frame (at the origin, looking along
    /// +z, y down), focal length `width` pixels (a 53° horizontal field of
    /// view), principal point at the image centre. For work where only the
    /// image size matters (losses, region pooling, tests).
    pub fn at_origin(width: u32, height: u32) -> Self {
        Self::looking_at(
            DVec3::ZERO,
            DVec3::Z,
            DVec3::NEG_Y,
            width,
            height,
            width as f64,
        )
    }

    /// World-to-camera transform.
    pub fn world_to_cam(&self) -> DAffine3 {
        self.cam_to_world.inverse()
    }

    /// Range of tx/tz and ty/tz the projection's Jacobian is evaluated in,
    /// `[lo_x, hi_x, lo_y, hi_y]`: the field of view widened on each side by
    /// [`GUARD_BAND`] × tan(fov/2).
    pub fn guard_band(&self) -> [f64; 4] {
        let tan_x = 0.5 * self.width as f64 / self.fx;
        let tan_y = 0.5 * self.height as f64 / self.fy;
        [
            -(self.cx / self.fx + GUARD_BAND * tan_x),
            (self.width as f64 - self.cx) / self.fx + GUARD_BAND * tan_x,
            -(self.cy / self.fy + GUARD_BAND * tan_y),
            (self.height as f64 - self.cy) / self.fy + GUARD_BAND * tan_y,
        ]
    }

    /// Pixel count.
    pub fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }

    /// Checks that the pose, intrinsics and depth range are finite and
    /// usable (errors name what is wrong).
    pub fn validate(&self) -> crate::Result<()> {
        let m = self.cam_to_world.matrix3;
        let finite = [self.fx, self.fy, self.cx, self.cy, self.near, self.far]
            .iter()
            .all(|v| v.is_finite())
            && self.cam_to_world.translation.is_finite()
            && m.is_finite();
        let ortho = (m.transpose() * m - glam::DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .all(|v| v.abs() < 1e-4)
            && m.determinant() > 0.0;
        if !finite || !ortho {
            return Err(crate::Error::bad_input(
                "camera pose",
                format!(
                    "must be a finite rotation + translation: {:?}",
                    self.cam_to_world
                ),
            ));
        }
        if self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(crate::Error::bad_input(
                "camera focal lengths",
                format!("must be positive, got fx={} fy={}", self.fx, self.fy),
            ));
        }
        if !(self.near > 0.0 && self.far > self.near) {
            return Err(crate::Error::bad_input(
                "camera depth range",
                format!(
                    "must satisfy 0 < near < far, got {}..{}",
                    self.near, self.far
                ),
            ));
        }
        if self.width == 0 || self.height == 0 || self.width > 16384 || self.height > 16384 {
            return Err(crate::Error::bad_input(
                "camera image size",
                format!("{}x{} outside 1..=16384", self.width, self.height),
            ));
        }
        Ok(())
    }
}
