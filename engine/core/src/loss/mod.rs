//! The mapping objective (paper Eqs. 6–9), forward and backward on the GPU:
//! photometric L1 + SSIM and depth L1 on rendered images ([`ImageLoss`]), the
//! feature loss on decoded region embeddings ([`FeatureLoss`]) and the
//! trust-region penalty that keeps the dictionary near its k-means anchor
//! ([`TrustRegion`]). CPU references: `latentam_reference::loss` and
//! `latentam_reference::ssim`.

mod feature;
mod image;
mod weights;

pub use feature::{FeatureLoss, TrustRegion, COSINE_EPS};
pub use image::{depth_is_valid, ImageLoss, ImageLossReadback, ImageLossValues};
pub use weights::{LossWeights, MAX_WEIGHT};

/// Per-row weights that make a loss over several views' regions the mean
/// over each view's regions, then the mean over views (a choice the paper
/// does not fix). `counts[v]` is the number of regions of view v; rows are
/// laid out view after view.
pub fn mean_per_view_weights(counts: &[u32]) -> Vec<f32> {
    let views = counts.iter().filter(|&&c| c > 0).count().max(1) as f32;
    counts
        .iter()
        .flat_map(|&c| std::iter::repeat_n(1.0 / (views * c as f32), c as usize))
        .collect()
}
