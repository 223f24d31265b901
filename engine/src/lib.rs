//! # latentam
//!
//! An online latent 3D Gaussian mapping engine on Vulkan compute: it builds a
//! map of Gaussians carrying geometry, colour and a 32-d query vector from a
//! stream of RGB-D frames, poses and vision-language embeddings, and decodes
//! rendered queries back into full embeddings through a learned dictionary.
//!
//! This crate is the library a robot program links; [`Mapper`] is its
//! façade. Its layers, each using only those before it (checked by
//! `tests/layers.rs`):
//! 1. [`error`](Error), [`files`], `settings`: the error type, whole-or-nothing
//!    files, and the one declaration of each configuration setting;
//! 2. [`gpu`] → [`ops`]: Vulkan, one way to dispatch a kernel, primitives;
//!    beside them [`io`]: logs in, checked frames out (host only);
//! 3. [`splat`] → [`loss`] → [`optim`] → [`latent`]: the rasterizer, the
//!    objective, Adam, and the dictionary decoder with its k-means;
//! 4. [`map`]: the global map, keyframes, seeding, PLY files;
//! 5. [`mapper`]: the per-keyframe loop, run folders, evaluation, the façade.
//!
//! [`reference`](mod@reference) holds the CPU implementation of every kernel's math: the
//! tests' oracle and the readable statement of what each kernel computes.
//! Production code never calls it.
//!
//! ```
//! use latentam::gpu::{Context, ContextOptions};
//! use latentam::ops::PrefixScan;
//!
//! let ctx = Context::new(ContextOptions::default())?;
//! let data = ctx.upload_new("example", &[3u32, 1, 4, 1, 5])?;
//! let scan = PrefixScan::new(&ctx, 5)?;
//! let mut rec = ctx.recorder()?;
//! scan.record(&mut rec, &data, 5)?;
//! rec.submit()?.wait()?;
//! assert_eq!(ctx.download::<u32>(&data)?, vec![0, 3, 4, 8, 9]);
//! # Ok::<(), latentam::Error>(())
//! ```

#![warn(missing_docs)]

mod error;
mod faults;
pub mod files;
pub mod gpu;
pub mod io;
pub mod latent;
pub mod loss;
pub mod map;
pub mod mapper;
pub mod ops;
pub mod optim;
mod random;
pub mod reference;
pub(crate) mod settings;
pub mod splat;

pub use error::{Error, Result};
/// The compiled kernel table (see the `latentam-shaders` crate).
pub use latentam_shaders as kernels;
pub use mapper::{Mapper, MapperConfig as Config};
