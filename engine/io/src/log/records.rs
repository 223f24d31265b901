//! What a log holds: channels, messages and metadata, and which of them a
//! reader is asked for.

use std::collections::BTreeMap;

/// Largest record (chunk or message) accepted, so a corrupt length field
/// cannot make the reader buffer the rest of a huge file.
pub const MAX_RECORD_BYTES: usize = 1 << 30;

/// A topic of the log and what its messages are.
///
/// ```no_run
/// use latentam_io::McapLog;
///
/// let log = McapLog::open("run.mcap".as_ref())?;
/// for c in log.channels().iter().filter(|c| c.schema_name == "sensor_msgs/msg/Image") {
///     println!("{}: {:?} images", c.topic, log.message_count(&c.topic));
/// }
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Channel {
    /// Topic name.
    pub topic: String,
    /// Schema (message type) name as written, e.g. `sensor_msgs/msg/Image`.
    pub schema_name: String,
    /// Schema encoding, `ros2msg` for ROS 2 logs.
    pub schema_encoding: String,
    /// Message encoding, `cdr` for ROS 2 logs.
    pub message_encoding: String,
}

impl Channel {
    /// A ROS 2 channel (`ros2msg` schema, `cdr` messages) of type `ty`.
    pub fn ros2(topic: &str, ty: &str) -> Self {
        Channel {
            topic: topic.into(),
            schema_name: ty.into(),
            schema_encoding: "ros2msg".into(),
            message_encoding: "cdr".into(),
        }
    }
}

/// One message, borrowed from the reader for the duration of a callback.
///
/// ```no_run
/// use latentam_io::{McapLog, PoseStamped, ReadFilter, RosMessage};
///
/// let log = McapLog::open("run.mcap".as_ref())?;
/// let mut reader = log.reader(ReadFilter { topics: Some(vec!["/camera/pose".into()]), ..Default::default() });
/// while let Some(read) = reader.next_with(|m| (m.log_time, PoseStamped::decode(m.data).map(|p| p.pose))) {
///     let (log_time, pose) = read?;
///     println!("{log_time} ns: {:?}", pose?.translation);
/// }
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct RawMessage<'a> {
    /// The channel it was published on.
    pub channel: &'a Channel,
    /// Log time, nanoseconds.
    pub log_time: u64,
    /// The serialized message.
    pub data: &'a [u8],
}

/// The key/value pairs of one MCAP metadata record.
///
/// ```no_run
/// let log = latentam_io::McapLog::open("run.mcap".as_ref())?;
/// for (name, record) in log.metadata()? {
///     let converter: Option<&String> = record.get("converter");
///     println!("{name}: {converter:?}");
/// }
/// # Ok::<(), latentam_io::InputError>(())
/// ```
pub type Metadata = BTreeMap<String, String>;

/// Which messages to read.
///
/// ```no_run
/// use latentam_io::{McapLog, ReadFilter};
///
/// let log = McapLog::open("run.mcap".as_ref())?;
/// let (start, _end) = log.time_range().unwrap_or_default();
/// // The colour images of the first ten seconds.
/// let filter = ReadFilter {
///     topics: Some(vec!["/camera/color/image_raw".into()]),
///     start_ns: Some(start),
///     end_ns: Some(start + 10_000_000_000),
/// };
/// let mut reader = log.reader(filter);
/// while let Some(bytes) = reader.next_with(|m| m.data.len()) {
///     println!("{} bytes", bytes?);
/// }
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone, Debug, Default)]
pub struct ReadFilter {
    /// Only these topics (all when `None`).
    pub topics: Option<Vec<String>>,
    /// Only messages with log time ≥ this, nanoseconds.
    pub start_ns: Option<u64>,
    /// Only messages with log time < this, nanoseconds.
    pub end_ns: Option<u64>,
}

impl ReadFilter {
    pub(super) fn admits(&self, topic: &str, log_time: u64) -> bool {
        self.topics
            .as_ref()
            .is_none_or(|t| t.iter().any(|x| x == topic))
            && self.start_ns.is_none_or(|s| log_time >= s)
            && self.end_ns.is_none_or(|e| log_time < e)
    }
}

pub(super) fn channel_of(c: &mcap::Channel<'_>) -> Channel {
    let (schema_name, schema_encoding) = c
        .schema
        .as_ref()
        .map(|s| (s.name.clone(), s.encoding.clone()))
        .unwrap_or_default();
    Channel {
        topic: c.topic.clone(),
        schema_name,
        schema_encoding,
        message_encoding: c.message_encoding.clone(),
    }
}
