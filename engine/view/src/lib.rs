//! latentam maps in Foxglove, through the official `foxglove` crate: the
//! same topics and Foxglove message types (protobuf, with the schemas the
//! crate carries) are written to MCAP files ([`write_foxglove_file`], behind
//! `latentam export --foxglove`) and served live over the Foxglove
//! WebSocket protocol while a map grows ([`LiveView`], behind
//! `latentam map --live`).
//!
//! | topic | type | what |
//! |---|---|---|
//! | `/latentam/map` | `foxglove.PointCloud` | a point per Gaussian (within a budget), colour, alpha = opacity, an `opacity` field |
//! | `/latentam/relevance/WORD` | `foxglove.PointCloud` | the same points coloured by relevance to a word, a `relevance` field |
//! | `/latentam/trajectory` | `foxglove.PosesInFrame` | the keyframe poses |
//! | `/latentam/camera` | `foxglove.PoseInFrame` | the last keyframe's pose (live) |
//! | `/latentam/image` | `foxglove.RawImage` | the last keyframe's colour image (live) |
//! | `/latentam/render` | `foxglove.RawImage` | the map rendered from that camera (live) |

mod file;
mod live;
mod map_points;
mod messages;
mod topics;

#[cfg(test)]
mod tests;

pub use file::write_foxglove_file;
pub use live::{
    LiveView, ViewOptions, ViewStats, ViewWord, CAMERA_TOPIC, IMAGE_TOPIC, MAP_TOPIC,
    RELEVANCE_PREFIX, RENDER_TOPIC, TRAJECTORY_TOPIC,
};
pub use map_points::{heat, heat_rgba, MapPoints};
pub use messages::{
    point_cloud, pose_in_frame, poses_in_frame, raw_image, topic_word, Cloud, PointValue, RgbImage,
};
pub use topics::Topics;
