//! # latentam-reference
//!
//! CPU implementations of every kernel's math, in plain readable Rust (f64
//! where precision matters). They are the oracle of the GPU tests and the
//! documentation of what each kernel computes.
//!
//! The library never links this crate: the engine's crates take it as a
//! dev-dependency for their tests, and the command-line tool's `selfcheck`
//! and `bench raster` compare the device against it on the user's machine.

#![warn(missing_docs)]

pub mod adam;
pub mod atomic;
pub mod decoder;
pub mod gemm;
pub mod grid;
pub mod kmeans;
pub mod loss;
pub mod metrics;
pub mod normalize;
pub mod pooling;
pub mod prune;
pub mod raster;
pub mod reduce;
pub mod rows;
pub mod scan;
pub mod softmax;
pub mod sort;
pub mod ssim;
pub mod targets;

pub use latentam_base::{Error, Result};
