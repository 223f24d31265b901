//! # latentam-io
//!
//! The engine's file formats: MCAP logs of ROS 2 messages in, [`Frame`]s
//! out, and the maps and trajectories a run writes.
//!
//! * [`cdr`]: zero-copy CDR decoding (and encoding, for writers and tests);
//! * [`messages`]: the message types, borrowed from the serialized bytes;
//! * [`schema`]: their `ros2msg` schema texts (the engine's own `.msg`
//!   files live in `engine/msg/`);
//! * [`McapLog`]: memory-mapped, indexed reading of a file or a rosbag2
//!   directory;
//! * [`open_input`] and friends: opening what a user names as an input
//!   only when it is a regular file (a FIFO would block forever);
//! * [`McapFrames`] / [`FrameAssembler`]: stamp pairing of colour, depth,
//!   intrinsics, pose and embeddings into checked [`Frame`]s, with every
//!   unused message counted in an [`IngestReport`];
//! * [`embedding_files`]: the embedding files users bring (`.npy` and
//!   safetensors: per-frame features, class vectors, query vectors);
//! * [`LogWriter`]: writing logs (converters, the demo scene, tests);
//! * [`trajectory`]: camera trajectories in the TUM RGB-D format
//!   ([`write_tum`] / [`read_tum`]).
//!
//! ```no_run
//! use latentam_io::{AssemblyConfig, McapFrames};
//!
//! let frames = McapFrames::open("run.mcap".as_ref(), AssemblyConfig::default())?;
//! for frame in frames {
//!     let frame = frame?;
//!     println!("frame at {} ns, pose {:?}", frame.stamp_ns, frame.pose.translation);
//! }
//! # Ok::<(), latentam_io::InputError>(())
//! ```

#![warn(missing_docs)]

pub mod cdr;
mod class_names;
pub mod codec;
pub mod embedding_files;
mod frame;
mod frame_check;
mod frames;
mod input;
mod json_keys;
mod log;
mod mcap_frames;
pub mod messages;
mod parts;
mod pool;
mod registration;
mod report;
pub mod schema;
mod tf;
mod topic_plan;
pub mod trajectory;
mod vocabulary;
mod writer;

pub use class_names::{parse_class_names, read_class_names, CLASS_NAMES_METADATA};
pub use frame::{
    decode_floats, embedding_space, encode_floats, CameraPose, ColorImage, DepthData, DepthImage,
    Dtype, EmbeddingLayout, Embeddings, Frame, Intrinsics, LabelImage, PixelFormat, MIN_DEPTH_M,
};
pub use frames::{AssemblyConfig, BadInputPolicy, FrameAssembler, PoseSource, TopicChoice, Topics};
pub use input::{
    check_input_file, open_input, read_input, read_input_to_string, MAX_BINARY_BYTES,
    MAX_TEXT_BYTES,
};
pub use json_keys::{check_json_keys, check_safetensors_keys, parse_json};
pub use latentam_base::{Error, InputError, Rejection, Result};
pub use log::{
    Channel, McapLog, MessageReader, Metadata, RawMessage, ReadFilter, MAX_RECORD_BYTES,
};
pub use mcap_frames::{McapFrames, PlannedInput};
pub use messages::{
    CameraInfo, CompressedImage, DiagnosticArray, DiagnosticStatus, FeatureGrid, Header, Image,
    MaskFeatures, Odometry, Path, PointCloud2, PointField, Pose, PoseStamped, RosMessage,
    StringMessage, TextEmbeddings, TfMessage, Time, TransformStamped,
};
pub use parts::MAX_EMBEDDING_DIM;
pub use registration::DepthRegistration;
pub use report::{IngestReport, ReasonCount};
pub use tf::{PoseTrack, TfBuffer, QUATERNION_NORM_TOLERANCE};
pub use topic_plan::plan_topics;
pub use trajectory::{read_tum, write_tum};
pub use vocabulary::{read_vocabulary, Vocabulary};
pub use writer::{Compression, LogWriter};

#[cfg(test)]
mod tests;
