//! CPU implementations of every kernel's math, in plain readable Rust (f64
//! where precision matters). They are the oracle of the GPU tests and the
//! documentation of what each kernel computes.

pub mod adam;
pub mod atomic;
pub mod decoder;
pub mod gemm;
pub mod kmeans;
pub mod loss;
pub mod metrics;
pub mod normalize;
pub mod pooling;
pub mod raster;
pub mod reduce;
pub mod scan;
pub mod softmax;
pub mod sort;
pub mod ssim;
