//! Optimisers. Adam on the GPU, one [`AdamGroup`] per parameter tensor
//! (Gaussian means, scales, ..., the projection W, the dictionary D), each
//! with its own hyper-parameters. CPU reference: `latentam_reference::adam`.

mod adam;
mod gaussians;

pub use adam::{AdamGroup, AdamHyper};
pub use gaussians::{GaussianLearningRates, GaussianOptimizer};
