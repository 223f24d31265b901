//! A Gaussian in f64, the thresholds the kernels compare against, and the
//! rendered images with their gradients.

#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use glam::DMat3;

use latentam_base::{HostGaussians, QUERY_DIM};
use latentam_shaders::shared;

/// Largest alpha a single Gaussian may contribute.
pub const MAX_ALPHA: f64 = shared::MAX_ALPHA as f64;

/// Contributions with smaller alpha are skipped.
pub const MIN_ALPHA: f64 = shared::MIN_ALPHA as f64;

/// A pixel stops when its transmittance would fall below this.
pub const MIN_TRANSMITTANCE: f64 = shared::MIN_TRANSMITTANCE as f64;

/// Low-pass filter added to the 2-D covariance (pixels²).
pub const LOW_PASS: f64 = shared::LOW_PASS as f64;

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

    pub(crate) fn opacity(&self) -> f64 {
        sigmoid(self.opacity_logit)
    }
}

pub(crate) fn sigmoid(x: f64) -> f64 {
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
