//! # latentam
//!
//! An online latent 3D Gaussian mapping engine on Vulkan compute: it builds a
//! map of Gaussians carrying geometry, colour and a 32-d query vector from a
//! stream of RGB-D frames, poses and vision-language embeddings, and decodes
//! rendered queries back into full embeddings through a learned dictionary.
//!
//! This crate is the library a robot program links. Its layers:
//! * [`gpu`]: the Vulkan context, memory accounting, buffers with explicit
//!   staging, one way to declare and dispatch a kernel, and a timestamp
//!   profiler;
//! * [`ops`]: GPU primitives built on it (prefix scan, reduction, GEMM, row
//!   softmax, radix sort, float scatter-add);
//! * [`splat`]: Gaussian storage and the differentiable rasterizer;
//! * [`latent`]: region pooling, the dictionary attention decoder and the
//!   streaming k-means that maintains the dictionary;
//! * [`loss`]: the mapping objective (photometric, depth, feature and
//!   trust-region terms) with its gradients;
//! * [`optim`]: Adam with per-tensor parameter groups;
//! * [`map`]: the CPU global map (voxel hash), keyframe selection and
//!   Gaussian seeding;
//! * [`mapper`]: the per-keyframe mapping loop (in progress: keyframe
//!   history);
//! * [`io`]: MCAP logs of ROS 2 messages in, checked frames out, and log
//!   writing;
//! * [`reference`]: CPU implementations of every kernel's math, the oracle of
//!   the tests and the readable statement of what each kernel computes.
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
pub mod splat;

pub use error::{Error, Result};
/// The compiled kernel table (see the `latentam-shaders` crate).
pub use latentam_shaders as kernels;
pub use mapper::{Mapper, MapperConfig as Config};
