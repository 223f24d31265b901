//! The channels a map is published on: one foxglove [`Context`] whose
//! sinks (an MCAP file, a WebSocket server) receive every message, with
//! one protobuf channel per topic (Foxglove's schema for its type) made
//! on first use.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use foxglove::messages::{PointCloud, PoseInFrame, PosesInFrame, RawImage};
use foxglove::{Context, Encode, PartialMetadata, RawChannel};

use latentam_base::{Error, Result};
use latentam_io::CameraPose;

use crate::messages::{self, Cloud, PointValue, RgbImage};

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
    point_value: PointValue,
    channels: Mutex<BTreeMap<String, Arc<RawChannel>>>,
}

impl Topics {
    /// Topics whose messages are in the `frame_id` frame (images are in
    /// their own camera frame), on a context of their own. Clouds carry
    /// their values as FLOAT32 (see [`Topics::with_point_value`]).
    pub fn new(frame_id: &str) -> Self {
        Topics {
            context: Context::new(),
            frame_id: frame_id.to_string(),
            point_value: PointValue::Float32,
            channels: Mutex::new(BTreeMap::new()),
        }
    }

    /// These topics with clouds whose values are packed as `value`.
    pub fn with_point_value(mut self, value: PointValue) -> Self {
        self.point_value = value;
        self
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

    /// Makes the channel of `topic` for messages of type `M` (one of
    /// [`foxglove::messages`]' types) if it is not there yet, so clients
    /// see it before its first message. A topic keeps the type it was
    /// made with.
    pub fn advertise<M: Encode>(&self, topic: &str) -> Result<Arc<RawChannel>> {
        let mut channels = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        let schema = M::get_schema();
        if let Some(c) = channels.get(topic) {
            let same = c.schema().map(|s| &s.name) == schema.as_ref().map(|s| &s.name);
            if !same {
                return Err(Error::bad_input(
                    format!("the topic {topic}"),
                    format!(
                        "it carries {}, not {}",
                        c.schema().map_or("no schema", |s| s.name.as_str()),
                        schema.as_ref().map_or("no schema", |s| s.name.as_str())
                    ),
                ));
            }
            return Ok(c.clone());
        }
        let mut builder = self
            .context
            .channel_builder(topic)
            .message_encoding(M::get_message_encoding());
        if let Some(schema) = schema {
            builder = builder.schema(schema);
        }
        let channel = builder
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
    fn publish<M: Encode>(&self, topic: &str, stamp_ns: u64, message: &M) -> Result<usize> {
        let channel = self.advertise::<M>(topic)?;
        if !channel.has_sinks() {
            return Ok(0);
        }
        let mut bytes = Vec::with_capacity(message.encoded_len().unwrap_or(0));
        message
            .encode(&mut bytes)
            .map_err(|e| Error::bad_input(format!("a message on {topic}"), e.to_string()))?;
        channel.log_with_meta(&bytes, PartialMetadata::with_log_time(stamp_ns));
        Ok(bytes.len())
    }

    /// Publishes `cloud` (`foxglove.PointCloud`) on `topic`; the bytes sent.
    pub fn cloud(&self, topic: &str, stamp_ns: u64, cloud: &Cloud<'_>) -> Result<usize> {
        let message = messages::point_cloud(&self.frame_id, stamp_ns, cloud, self.point_value)?;
        self.publish::<PointCloud>(topic, stamp_ns, &message)
    }

    /// Publishes `poses` (camera-to-world, in order) as one path
    /// (`foxglove.PosesInFrame`) on `topic`; the bytes sent.
    pub fn poses(&self, topic: &str, stamp_ns: u64, poses: &[CameraPose]) -> Result<usize> {
        let message = messages::poses_in_frame(&self.frame_id, stamp_ns, poses);
        self.publish::<PosesInFrame>(topic, stamp_ns, &message)
    }

    /// Publishes one pose (`foxglove.PoseInFrame`) on `topic`; the bytes sent.
    pub fn pose(&self, topic: &str, stamp_ns: u64, pose: &CameraPose) -> Result<usize> {
        let message = messages::pose_in_frame(&self.frame_id, stamp_ns, pose);
        self.publish::<PoseInFrame>(topic, stamp_ns, &message)
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
        self.publish::<RawImage>(topic, stamp_ns, &message)
    }
}
