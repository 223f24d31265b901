//! The last keyframe as a live handle hands it to viewers.

use latentam_io::ColorImage;

use crate::splat::Camera;

/// The last keyframe as the camera saw it: its colour image, camera and
/// stamp, for a viewer to show beside the map rendered from the same
/// camera.
#[derive(Clone, Debug)]
pub struct KeyframeImage {
    /// The keyframe's index in the map (0 for its first).
    pub keyframe: u64,
    /// The frame's stamp, ns.
    pub stamp_ns: i64,
    /// Its camera: pose and intrinsics.
    pub camera: Camera,
    /// Its colour image, as submitted.
    pub color: ColorImage,
}
