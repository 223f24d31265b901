//! # latentam-core
//!
//! latentam's mapping engine, in the paper's order: the differentiable
//! Gaussian rasterizer ([`splat`]), the mapping objective ([`loss`]), Adam
//! ([`optim`]), the latent head with its dictionary decoder and streaming
//! k-means ([`latent`]), the global map and its GPU window ([`map`]), and
//! the per-keyframe loop with its run folders and evaluation ([`mapper`]).
//! Each module uses only those before it in this list
//! (`engine/core/tests/layers.rs` checks it); the crates below it, the
//! Vulkan layer (`latentam-gpu`) and the log reader (`latentam-io`), cannot
//! see it at all.
//!
//! Robot programs depend on the `latentam` crate, whose small API is built
//! on this one.
//!
//! ```no_run
//! use latentam_core::mapper::{Mapper, MapperConfig};
//!
//! let mapper = Mapper::new(MapperConfig::default())?;
//! println!("{} atoms, voxel {} m", mapper.config().atoms, mapper.config().voxel_size);
//! # Ok::<(), latentam_core::Error>(())
//! ```

#![warn(missing_docs)]

pub mod latent;
pub mod live;
pub mod loss;
pub mod map;
pub mod mapper;
pub mod optim;
pub mod splat;

#[cfg(test)]
mod device_limits_tests;

pub use latentam_base::{Error, Result};
