//! The ROS 2 message types the engine reads and writes, decoded in place.
//!
//! Each type borrows its strings and arrays from the serialized bytes
//! ([`Seq`](crate::cdr::Seq) for numeric arrays, `&[u8]` for payloads), so
//! decoding an image message costs a few field reads whatever the image
//! size. Each type's wire layout is written once (`cdr_message!` in
//! `message.rs`); decoding and encoding both follow it.

#[macro_use]
mod message;
mod common;
mod geometry;
mod latentam;
mod published;
mod sensor;

pub use common::{Header, Pose, Time};
pub use geometry::{Odometry, PoseStamped, TfMessage, TransformStamped};
pub use latentam::{FeatureGrid, MaskFeatures, TextEmbeddings};
pub use message::RosMessage;
pub use published::{
    DiagnosticArray, DiagnosticStatus, Path, PointCloud2, PointField, StringMessage,
};
pub use sensor::{CameraInfo, CompressedImage, Image};
