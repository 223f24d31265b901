//! The weights of the mapping objective's terms (paper Eqs. 6–9).

use latentam_base::settings;

settings! {
    /// Weights of every loss term. Defaults are the paper's values.
    ///
    /// The total is `rgb · (rgb_l1 · L1 + ssim · (1 − SSIM)) + depth · L_depth +
    /// feature · (cosine · L_cos + l2 · L_l2 + trust_region · L_trust)`. The
    /// paper's 0.2/0.8 split between L1 and SSIM is the reverse of every
    /// reference 3DGS system (0.8/0.2); swap it here if wanted.
    ///
    /// ```
    /// use latentam_core::loss::LossWeights;
    ///
    /// // The usual 3DGS split of the photometric term (0.8 L1, 0.2 SSIM).
    /// let weights = LossWeights { rgb_l1: 0.8, ssim: 0.2, ..Default::default() };
    /// assert_eq!(weights.feature, 5.0);
    /// assert_eq!(weights.trust_radius, 0.1);
    /// ```
    #[derive(Copy)]
    pub struct LossWeights {
        /// lambda_rgb, weight of the photometric term (not given by the
        /// paper).
        pub rgb: f32 = 1.0 => value().range(0.0, MAX_WEIGHT),
        /// lambda_I1, share of L1 in the photometric term.
        pub rgb_l1: f32 = 0.2 => value().range(0.0, MAX_WEIGHT),
        /// lambda_I2, share of 1 - SSIM in the photometric term.
        pub ssim: f32 = 0.8 => value().range(0.0, MAX_WEIGHT),
        /// lambda_d, weight of the depth L1 term, on pixels with a valid
        /// measured depth.
        pub depth: f32 = 0.1 => value().range(0.0, MAX_WEIGHT),
        /// lambda_f, weight of the whole feature loss.
        pub feature: f32 = 5.0 => value().range(0.0, MAX_WEIGHT),
        /// lambda_cos, weight of the cosine term inside the feature loss.
        pub cosine: f32 = 0.5 => value().range(0.0, MAX_WEIGHT),
        /// lambda_2, weight of the mean-squared-error term inside the
        /// feature loss.
        pub l2: f32 = 0.5 => value().range(0.0, MAX_WEIGHT),
        /// lambda_D, weight of the trust-region term inside the feature
        /// loss, which keeps the dictionary near its k-means anchor.
        pub trust_region: f32 = 0.2 => value().range(0.0, MAX_WEIGHT),
        /// delta, the trust-region radius: how far (L2 norm, per atom) the
        /// dictionary may move from its anchor before the term applies.
        pub trust_radius: f32 = 0.1 => value().range(0.0, MAX_WEIGHT),
    }
}

/// Largest loss weight: far beyond any useful value, weights overflow f32
/// in the first step (`rgb = 1e30` made the state infinite).
pub const MAX_WEIGHT: f32 = 1e4;
