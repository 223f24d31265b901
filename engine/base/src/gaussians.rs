//! Gaussian parameters on the host: the structure-of-arrays layout the
//! GPU buffers mirror, the saved map stores and the CPU references read.

use crate::{Error, Result};

/// Channels of a Gaussian's latent query vector.
pub const QUERY_DIM: usize = 32;

/// Gaussians on the host, one entry per Gaussian in every field.
///
/// Parameters are stored as the optimiser sees them: the scale as its log,
/// the rotation as an unnormalised quaternion `(w, x, y, z)`, the opacity as
/// a logit (opacity = sigmoid(logit)), the colour as view-independent linear
/// RGB.
///
/// ```
/// use latentam_base::HostGaussians;
///
/// let mut g = HostGaussians::zeros(2);
/// g.means[1] = [0.0, 0.0, 1.5];
/// g.quats = vec![[1.0, 0.0, 0.0, 0.0]; 2];
/// g.log_scales = vec![[0.02f32.ln(); 3]; 2]; // 2 cm
/// g.opacity_logits = vec![2.0; 2]; // opacity ≈ 0.88
/// assert_eq!(g.len()?, 2);
/// g.colors.pop();
/// assert!(g.len().is_err()); // every field needs one entry per Gaussian
/// # Ok::<(), latentam_base::Error>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HostGaussians {
    /// Centres, world frame, metres.
    pub means: Vec<[f32; 3]>,
    /// Natural log of the per-axis standard deviations.
    pub log_scales: Vec<[f32; 3]>,
    /// Rotation quaternions `(w, x, y, z)`, normalised where used.
    pub quats: Vec<[f32; 4]>,
    /// RGB colour.
    pub colors: Vec<[f32; 3]>,
    /// Opacity logits.
    pub opacity_logits: Vec<f32>,
    /// Latent query vectors.
    pub queries: Vec<[f32; QUERY_DIM]>,
}

impl HostGaussians {
    /// `n` Gaussians with every parameter zero.
    pub fn zeros(n: usize) -> Self {
        Self {
            means: vec![[0.0; 3]; n],
            log_scales: vec![[0.0; 3]; n],
            quats: vec![[0.0; 4]; n],
            colors: vec![[0.0; 3]; n],
            opacity_logits: vec![0.0; n],
            queries: vec![[0.0; QUERY_DIM]; n],
        }
    }

    /// Room for `more` Gaussians in every field.
    pub fn reserve(&mut self, more: usize) {
        self.means.reserve(more);
        self.log_scales.reserve(more);
        self.quats.reserve(more);
        self.colors.reserve(more);
        self.opacity_logits.reserve(more);
        self.queries.reserve(more);
    }

    /// Number of Gaussians; errors if the fields disagree.
    pub fn len(&self) -> Result<usize> {
        let n = self.means.len();
        let lens = [
            self.log_scales.len(),
            self.quats.len(),
            self.colors.len(),
            self.opacity_logits.len(),
            self.queries.len(),
        ];
        if lens.iter().any(|&l| l != n) {
            return Err(Error::bad_input(
                "Gaussian fields",
                format!(
                    "different lengths: means {n}, log_scales {}, quats {}, colors {}, \
                     opacity_logits {}, queries {}",
                    lens[0], lens[1], lens[2], lens[3], lens[4]
                ),
            ));
        }
        Ok(n)
    }

    /// Whether there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }
}
