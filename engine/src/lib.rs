//! # latentam
//!
//! An online latent 3D Gaussian mapping engine on Vulkan compute: it builds a
//! map of Gaussians carrying geometry, colour and a 32-d query vector from a
//! stream of RGB-D frames, poses and vision-language embeddings, and decodes
//! rendered queries back into full embeddings through a learned dictionary.
//!
//! This crate is what a robot program depends on. [`LiveMapper`] maps on
//! a worker thread: the robot's loop only enqueues frames, and any thread
//! reads immutable snapshots of the map and asks relevance queries while
//! it grows. [`Mapper`] is the same engine driven synchronously (offline
//! use, tests), [`LogRun`] maps a whole recorded log into a run folder,
//! and [`frames`] holds what a frame is made of and how logs are read. The
//! engine behind it is split into crates along its layers, each seeing
//! only those below it:
//!
//! | crate | what |
//! |---|---|
//! | `latentam-base` | errors, whole-or-nothing files, settings, the camera and host-side Gaussians |
//! | `latentam-gpu` | Vulkan: device, memory, the one way to dispatch a kernel, the profiler, GPU primitives |
//! | `latentam-io` | MCAP logs and rosbag2 folders in, checked frames out |
//! | `latentam-core` | the rasterizer, the objective, Adam, the latent head, the map, the per-keyframe loop, the live handle |
//! | `latentam-reference` | the CPU statement of every kernel's math; tests and `selfcheck` only |
//! | `latentam-view` | the map in Foxglove: MCAP files and a live WebSocket view (feature `view`) |
//!
//! ```no_run
//! use latentam::frames::Frame;
//! use latentam::{LiveMapper, LiveOptions, TextQuery};
//!
//! # fn camera_frames() -> Vec<Frame> { Vec::new() }
//! # let chair_embedding = vec![0.0f32; 512];
//! // Every kernel is compiled before `new` returns: the first frame does not wait.
//! let live = LiveMapper::new(latentam::Config::default(), LiveOptions::default())?;
//! for frame in camera_frames() {
//!     live.submit(frame)?; // returns at once; a full queue drops frames by policy
//! }
//! // From any thread, while mapping goes on: which Gaussians are the chair?
//! let answer = live.relevance(&TextQuery::embedding(chair_embedding))?;
//! println!("{} Gaussians, keyframe {}", answer.scores.len(), answer.snapshot.keyframes);
//! println!("{:?}", live.status().dropped); // frames given up, by reason
//! let mut mapper = live.finish()?; // maps what is queued
//! mapper.save("out/")?; // out/state.latentam: resume or query later
//! # Ok::<(), latentam::Error>(())
//! ```

#![warn(missing_docs)]

pub use latentam_base::{Camera, Error, HostGaussians, InputError, Result};
pub use latentam_core::latent::{Relevance as Scoring, TextQuery};
pub use latentam_core::live::{
    DropCounts, KeyframeImage, LiveMapper, LiveOptions, LiveReader, LiveStatus, LogRun,
    LogRunOptions, Relevance, RunObserver,
};
pub use latentam_core::map::Gaussian;
pub use latentam_core::mapper::eval::ViewMetrics;
pub use latentam_core::mapper::{
    DecoderFile, Ending, IndexSettings, Integrated, KeyframeReport, MapSnapshot, Mapper,
    MapperConfig as Config, MapperStats, RelevanceIndex, RunReport, Scored, Viewpoint,
};
pub use latentam_core::splat::RenderedView;
pub use latentam_gpu::{Context, ContextOptions, DeviceInfo};

/// What a frame is made of, and reading frames from MCAP logs and rosbag2
/// folders.
pub mod frames {
    pub use latentam_io::{
        encode_floats, read_vocabulary, AssemblyConfig, BadInputPolicy, CameraPose, ColorImage,
        DepthData, DepthImage, Dtype, EmbeddingLayout, Embeddings, Frame, IngestReport, Intrinsics,
        LabelImage, McapFrames, PixelFormat, PoseSource, TopicChoice, Topics, Vocabulary,
    };
}

/// Building a [`Config`] the way the command-line tool and the ROS node
/// do: from a TOML file, a named preset and `key=value` overrides.
///
/// ```no_run
/// use latentam::config::{apply_overrides, read_input_to_string, Preset};
///
/// // Bounded: a file far larger than any configuration is refused.
/// let text = read_input_to_string("mapper.toml".as_ref())?;
/// let base = latentam::Config::from_toml(&text)?;
/// let quality = "quality".parse::<Preset>()?.apply(&base)?;
/// let config = apply_overrides(&quality, &["gpu_budget=2000000000".to_string()])?;
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub mod config {
    pub use latentam_core::mapper::{apply_overrides, documented_defaults, Preset};
    pub use latentam_io::read_input_to_string;
}

/// The embedding files users bring, `.npy` arrays and safetensors files:
/// one frame's embeddings from a feature extractor, the class vectors and
/// class-id images oracle embeddings are made of, and a vector to query a
/// map with. Each reader takes a file's bytes (or, [`read_vector`], its
/// path) and refuses what it cannot use with [`Error::InvalidArgument`]
/// naming the file; none panics on any bytes.
///
/// [`read_vector`]: crate::embedding_files::read_vector
///
/// ```no_run
/// use latentam::embedding_files::{features_from_safetensors, read_vector, FrameFeatures};
/// use latentam::TextQuery;
///
/// // A text embedding from a vision-language model, saved with `np.save`.
/// let chair = read_vector("chair.npy".as_ref())?;
/// let query = TextQuery::embedding(chair);
/// // One frame's region embeddings, as `latentam convert --features` reads them.
/// let bytes = std::fs::read("frame-000000.safetensors")?;
/// let frame = features_from_safetensors(&bytes, "frame-000000.safetensors", None)?;
/// if let FrameFeatures::Regions { count, .. } = frame.features {
///     println!("{count} regions of {}-d {} embeddings", frame.dim, frame.model);
/// }
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub mod embedding_files {
    pub use latentam_io::embedding_files::{
        class_ids_from_npy, features_from_safetensors, grid_from_npy, npy, read_vector,
        regions_from_npy, vector_from_bytes, ClassVectors, FrameFeatures, LoadedFeatures,
    };
}

/// A live view of the map in Foxglove (feature `view`): a WebSocket
/// server publishing the map, trajectory, keyframe images and relevance
/// clouds while mapping goes on.
///
/// ```no_run
/// use latentam::view::{LiveView, ViewOptions};
/// let live = latentam::LiveMapper::new(Default::default(), Default::default())?;
/// let view = LiveView::serve(live.reader(), ViewOptions::default())?; // ws://127.0.0.1:8765
/// # Ok::<(), latentam::Error>(())
/// ```
#[cfg(feature = "view")]
pub mod view {
    pub use latentam_view::{LiveView, ViewOptions, ViewStats, ViewWord};
}
