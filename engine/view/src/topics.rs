//! The channels a map is published on: one foxglove [`Context`] whose
//! sinks (an MCAP file, a WebSocket server) receive every message, with
//! one JSON channel per topic made on first use.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use foxglove::{Context, PartialMetadata, RawChannel, Schema};
use serde_json::Value;

use latentam_base::{Error, Result};
use latentam_io::CameraPose;

use crate::messages::{self, Cloud, RgbImage};
use crate::schemas;

/// Topics in one world frame, published to every sink of its context.
///
/// ```
/// use latentam_view::{Cloud, Topics};
///
/// let topics = Topics::new("map");
/// // No sink yet: nothing is written, and nothing fails.
/// let cloud = Cloud { positions: &[[0.0, 0.0, 1.0]], colours: &[[255, 0, 0, 255]], value: ("opacity", &[1.0]) };
/// topics.cloud("/latentam/map", 1_000, &cloud)?;
/// assert!(!topics.subscribed("/latentam/map"));
/// # Ok::<(), latentam_base::Error>(())
/// ```
pub struct Topics {
    context: Arc<Context>,
    frame_id: String,
    channels: Mutex<BTreeMap<String, Arc<RawChannel>>>,
}

impl Topics {
    /// Topics whose messages are in the `frame_id` frame (images are in
    /// their own camera frame), on a context of their own.
    pub fn new(frame_id: &str) -> Self {
        Topics {
            context: Context::new(),
            frame_id: frame_id.to_string(),
            channels: Mutex::new(BTreeMap::new()),
        }
    }

    /// The foxglove context: add sinks to it (see [`crate::write_foxglove_file`]
    /// and [`crate::LiveView`]).
    pub fn context(&self) -> &Arc<Context> {
        &self.context
    }

    /// The world frame of its messages.
    pub fn frame_id(&self) -> &str {
        &self.frame_id
    }

    /// Makes the channel of `topic` with `schema` (one of
    /// [`crate::schemas`]'s names) if it is not there yet, so clients see
    /// it before its first message.
    pub fn advertise(&self, topic: &str, schema: &str) -> Result<Arc<RawChannel>> {
        let mut channels = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(c) = channels.get(topic) {
            return Ok(c.clone());
        }
        let text = schemas::schema(schema)
            .ok_or_else(|| Error::bad_input("schema", format!("no schema named {schema}")))?
            .to_string();
        let channel = self
            .context
            .channel_builder(topic)
            .schema(Schema::new(schema, "jsonschema", text.into_bytes()))
            .message_encoding("json")
            .build_raw()
            .map_err(|e| Error::bad_input(format!("the channel {topic}"), e.to_string()))?;
        channels.insert(topic.to_string(), channel.clone());
        Ok(channel)
    }

    /// Whether a sink (a file, a viewer) takes the messages of `topic`.
    pub fn subscribed(&self, topic: &str) -> bool {
        self.channels
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(topic)
            .is_some_and(|c| c.has_sinks())
    }

    /// Publishes `message` on `topic` at `stamp_ns`; the bytes sent.
    fn publish(&self, topic: &str, schema: &str, stamp_ns: u64, message: &Value) -> Result<usize> {
        let channel = self.advertise(topic, schema)?;
        if !channel.has_sinks() {
            return Ok(0);
        }
        let bytes = serde_json::to_vec(message)
            .map_err(|e| Error::bad_input(format!("a message on {topic}"), e.to_string()))?;
        channel.log_with_meta(&bytes, PartialMetadata::with_log_time(stamp_ns));
        Ok(bytes.len())
    }

    /// Publishes `cloud` (`foxglove.PointCloud`) on `topic`; the bytes sent.
    pub fn cloud(&self, topic: &str, stamp_ns: u64, cloud: &Cloud<'_>) -> Result<usize> {
        let message = messages::point_cloud(&self.frame_id, stamp_ns, cloud)?;
        self.publish(topic, schemas::POINT_CLOUD, stamp_ns, &message)
    }

    /// Publishes `poses` (camera-to-world, in order) as one path
    /// (`foxglove.PosesInFrame`) on `topic`; the bytes sent.
    pub fn poses(&self, topic: &str, stamp_ns: u64, poses: &[CameraPose]) -> Result<usize> {
        let message = messages::poses_in_frame(&self.frame_id, stamp_ns, poses);
        self.publish(topic, schemas::POSES_IN_FRAME, stamp_ns, &message)
    }

    /// Publishes one pose (`foxglove.PoseInFrame`) on `topic`; the bytes sent.
    pub fn pose(&self, topic: &str, stamp_ns: u64, pose: &CameraPose) -> Result<usize> {
        let message = messages::pose_in_frame(&self.frame_id, stamp_ns, pose);
        self.publish(topic, schemas::POSE_IN_FRAME, stamp_ns, &message)
    }

    /// Publishes an image (`foxglove.RawImage`, `rgb8`) in the frame
    /// `frame_id` on `topic`; the bytes sent.
    pub fn image(
        &self,
        topic: &str,
        frame_id: &str,
        stamp_ns: u64,
        image: &RgbImage<'_>,
    ) -> Result<usize> {
        let message = messages::raw_image(frame_id, stamp_ns, image)?;
        self.publish(topic, schemas::RAW_IMAGE, stamp_ns, &message)
    }
}
