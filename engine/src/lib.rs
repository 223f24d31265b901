//! # latentam
//!
//! An online latent 3D Gaussian mapping engine on Vulkan compute: it builds a
//! map of Gaussians carrying geometry, colour and a 32-d query vector from a
//! stream of RGB-D frames, poses and vision-language embeddings, and decodes
//! rendered queries back into full embeddings through a learned dictionary.
//!
//! This crate is what a robot program depends on: [`Mapper`] maps frames
//! and answers queries, [`LogRun`] maps a whole recorded log into a run
//! folder, and [`frames`] holds what a frame is made of and how logs are
//! read. The engine behind it is split into crates along its layers, each
//! seeing only those below it:
//!
//! | crate | what |
//! |---|---|
//! | `latentam-base` | errors, whole-or-nothing files, settings, the camera and host-side Gaussians |
//! | `latentam-gpu` | Vulkan: device, memory, the one way to dispatch a kernel, the profiler, GPU primitives |
//! | `latentam-io` | MCAP logs and rosbag2 folders in, checked frames out |
//! | `latentam-core` | the rasterizer, the objective, Adam, the latent head, the map, the per-keyframe loop |
//! | `latentam-reference` | the CPU statement of every kernel's math; tests and `selfcheck` only |
//!
//! ```no_run
//! use latentam::frames::{AssemblyConfig, McapFrames};
//!
//! let mut mapper = latentam::Mapper::new(latentam::Config::default())?;
//! for frame in McapFrames::open("run.mcap".as_ref(), AssemblyConfig::default())? {
//!     mapper.integrate(&frame?)?; // keyframes are mapped, other frames skipped
//! }
//! mapper.save("out/")?; // out/state.latentam: resume or query later
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs)]

pub use latentam_base::{Camera, Error, HostGaussians, InputError, Result};
pub use latentam_core::latent::TextQuery;
pub use latentam_core::mapper::{
    LogRun, LogRunOptions, Mapper, MapperConfig as Config, RunObserver, RunReport,
};

/// What a frame is made of, and reading frames from MCAP logs and rosbag2
/// folders.
pub mod frames {
    pub use latentam_io::{
        read_vocabulary, AssemblyConfig, BadInputPolicy, CameraPose, ColorImage, DepthData,
        DepthImage, Embeddings, Frame, IngestReport, Intrinsics, LabelImage, McapFrames,
        PixelFormat, Topics, Vocabulary,
    };
}
