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
//! and [`frames`] holds what a frame is made of and how logs are read.
//! The other modules serve programs built around the engine, such as the
//! command-line tool and the ROS node: [`config`] (settings from files,
//! presets and overrides), [`embedding_files`], [`messages`] and [`logs`]
//! (ROS 2 messages and MCAP logs below the frames), [`runs`] (run
//! folders), [`interchange`] (PLY and TUM files), [`eval`], [`text`]
//! (printing untrusted text) and [`files`] (bounded reads, whole-or-nothing
//! writes). The engine behind it is split into crates along its layers,
//! each seeing only those below it:
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
pub use latentam_core::latent::{softmax_rows, Relevance as Scoring, TextQuery};
pub use latentam_core::live::{
    DropCounts, KeyframeImage, LiveMapper, LiveOptions, LiveReader, LiveStatus, LogRun,
    LogRunOptions, Relevance, RunObserver,
};
pub use latentam_core::map::Gaussian;
pub use latentam_core::mapper::eval::ViewMetrics;
pub use latentam_core::mapper::warm_up;
pub use latentam_core::mapper::{
    DecoderFile, Ending, IndexSettings, Integrated, KeyframeReport, MapSnapshot, Mapper,
    MapperConfig as Config, MapperStats, RelevanceIndex, RunReport, Scored, Viewpoint,
};
pub use latentam_core::splat::RenderedView;
pub use latentam_gpu::{Context, ContextOptions, DeviceInfo, LiveObjects, Validation};

/// What a frame is made of, and reading frames from MCAP logs and rosbag2
/// folders.
pub mod frames {
    pub use latentam_io::{
        encode_floats, read_class_names, read_vocabulary, AssemblyConfig, BadInputPolicy,
        CameraPose, ColorImage, DepthData, DepthImage, DepthRegistration, Dtype, EmbeddingLayout,
        Embeddings, Frame, IngestReport, Intrinsics, LabelImage, McapFrames, PixelFormat,
        PlannedInput, PoseSource, TopicChoice, Topics, Vocabulary,
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
    pub use latentam_core::map::KeyframePolicy;
    pub use latentam_core::mapper::{apply_overrides, documented_defaults, Preset};
    pub use latentam_io::read_input_to_string;
}

/// The embedding files users bring, `.npy` arrays and safetensors files:
/// one frame's embeddings from a feature extractor, the class vectors and
/// class-id images oracle embeddings are made of, and a vector to query a
/// map with. Each reader takes a file's bytes (or, [`read_vector`], its
/// path) and refuses what it cannot use, naming the file: [`Error::Damaged`]
/// for a file that is not the format it claims, [`Error::BadInput`] for
/// contents it cannot use; none panics on any bytes.
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

/// ROS 2 messages as the engine reads them from logs and a node
/// publishes them, and their encodings: [`cdr`], the ROS 2 wire format,
/// and [`codec`], image messages to and from pixels (JPEG, PNG,
/// `compressedDepth`).
///
/// [`cdr`]: crate::messages::cdr
/// [`codec`]: crate::messages::codec
pub mod messages {
    pub use latentam_io::{
        cdr, codec, CameraInfo, CompressedImage, DiagnosticArray, DiagnosticStatus, FeatureGrid,
        Header, Image, MaskFeatures, Path, PointCloud2, PointField, Pose, PoseStamped, RosMessage,
        StringMessage, TextEmbeddings, TfMessage, Time, TransformStamped,
    };
}

/// MCAP logs at the level of their messages, below [`frames`]: a log's
/// channels, metadata and raw messages read as recorded, and logs written
/// from [`messages`].
///
/// ```no_run
/// use latentam::logs::{Compression, LogWriter, McapLog};
/// use latentam::messages::StringMessage;
///
/// let log = McapLog::open("in.mcap".as_ref())?;
/// for channel in log.channels() {
///     let count = log.message_count(&channel.topic).unwrap_or(0);
///     println!("{} ({}): {count} messages", channel.topic, channel.schema_name);
/// }
/// let mut out = LogWriter::create("notes.mcap".as_ref(), Compression::Zstd)?;
/// out.write("/note", 1_000_000_000, &StringMessage { data: "hello" })?;
/// out.finish()?;
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub mod logs {
    pub use latentam_io::{
        Channel, Compression, LogWriter, McapLog, Metadata, RawMessage, ReadFilter,
        MAX_RECORD_BYTES,
    };
}

/// Run folders, what [`LogRun`] writes: the map saved in them
/// ([`STATE_FILE`]), the files they may hold, locking one to write it, and
/// reading one while a writer may replace it.
///
/// [`STATE_FILE`]: crate::runs::STATE_FILE
///
/// ```no_run
/// use latentam::runs::{read_one_version, RunFolder};
/// use latentam::Mapper;
///
/// let ctx = latentam::Context::new(Default::default())?;
/// let dir = std::path::Path::new("runs/kitchen");
/// // Reading takes no lock: a writer replaces the whole folder at once.
/// let mapper = read_one_version(dir, || Mapper::load(&ctx, dir))?;
/// println!("{} Gaussians", mapper.stats().gaussians);
/// // Writing does: a second writer is refused with `Error::Locked`.
/// let folder = RunFolder::lock(dir)?;
/// # Ok::<(), latentam::Error>(())
/// ```
pub mod runs {
    pub use latentam_core::live::{Kept, Written};
    pub use latentam_core::mapper::{
        read_one_version, RunFolder, DECODER_FILE, RUN_FOLDER_FILES, STATE_FILE,
    };

    /// A saved map's archive rebuilt from its header (as JSON, edited) and
    /// its data, with its checksum sealed again: for tests that craft
    /// saved maps the checksum would otherwise refuse.
    #[doc(hidden)]
    pub use latentam_core::mapper::archive_join_resealed;
}

/// The map and its trajectory in the formats other tools read: PLY files
/// of 3D Gaussian splats (with the query vectors and any extra per-Gaussian
/// fields) and TUM trajectories.
pub mod interchange {
    pub use latentam_core::map::{read_ply, unit_quat, write_ply, PlyMap};
    pub use latentam_io::{read_tum, write_tum};
}

/// Scoring a map against a log's semantic labels, as `latentam eval`
/// does: per-class pixel counts summed over views into IoU, and the
/// region-pooled scores; one view's metrics are a [`ViewMetrics`].
pub mod eval {
    pub use latentam_core::mapper::eval::{add_iou, mean_iou, ClassCounts, RegionPooled};
}

/// Printing text that came from files or the command line (a log's
/// vocabulary, a run id, a path, an error's causes) without letting it
/// reach the terminal as escape sequences or as megabytes on one line.
///
/// ```no_run
/// use latentam::text::{shown, shown_path};
///
/// let word = "chair\u{1b}[2J"; // read from a log: it could clear the screen
/// println!("{} in {}", shown(word), shown_path("runs/kitchen".as_ref()));
/// ```
pub mod text {
    pub use latentam_base::text::{shown, shown_path, with_causes};
}

/// Input files read with a bound on their size, and output files written
/// whole or not at all: a crash or a full disk leaves the file as it was
/// or no file, never half of one.
///
/// ```no_run
/// use latentam::files::{read_input_to_string, write_bytes_atomically, PartialFile};
///
/// let notes = read_input_to_string("notes.txt".as_ref())?; // refuses a huge file
/// write_bytes_atomically("copy.txt".as_ref(), notes.as_bytes())?;
/// // For a writer that takes a path: write there, then commit.
/// let out = PartialFile::new("scene.mcap".as_ref())?;
/// std::fs::write(out.path(), b"...")?;
/// out.commit()?; // dropped uncommitted, the partial file is removed
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub mod files {
    pub use latentam_base::files::{write_bytes_atomically, PartialFile};
    pub use latentam_io::{parse_json, read_input, read_input_to_string};
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
