//! Writing ROS 2 MCAP logs with the schemas of [`super::schema`].

use std::collections::{BTreeMap, HashMap};
use std::io::{BufWriter, Seek, Write};
use std::path::Path;

use super::messages::RosMessage;
use super::schema::schema_text;
use super::InputError;

/// Chunk compression of a written log.
///
/// ```no_run
/// use latentam_io::{Compression, LogWriter};
///
/// // lz4 for a log that is replayed often; zstd (the default) for archives.
/// let log = LogWriter::create("replay.mcap".as_ref(), Compression::Lz4)?;
/// log.finish()?;
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Compression {
    /// zstd (the default: best ratio for images and depth).
    #[default]
    Zstd,
    /// lz4 (faster to read, larger).
    Lz4,
    /// Uncompressed chunks.
    None,
}

/// Writes typed ROS 2 messages to an MCAP file, registering each topic's
/// channel and schema on first use.
///
/// ```
/// use latentam_io::{Compression, Header, LogWriter, PoseStamped, Pose};
///
/// let mut bytes = std::io::Cursor::new(Vec::new());
/// let mut log = LogWriter::new(&mut bytes, Compression::Zstd)?;
/// let pose = PoseStamped { header: Header::at(1_000, "map"), pose: Pose::IDENTITY };
/// log.write("/camera/pose", 1_000, &pose)?;
/// log.finish()?;
/// # Ok::<(), latentam_io::InputError>(())
/// ```
pub struct LogWriter<W: Write + Seek> {
    inner: mcap::Writer<W>,
    schemas: HashMap<&'static str, u16>,
    channels: HashMap<String, (u16, &'static str)>,
    sequence: u32,
}

/// A failed write, with its causes: the MCAP writer's "I/O error from
/// writing" alone does not say that the disk is full or the file too
/// large.
fn write_error(e: impl std::error::Error) -> InputError {
    InputError::Write(latentam_base::text::with_causes(&e))
}

impl LogWriter<BufWriter<std::fs::File>> {
    /// Creates (truncates) a file.
    pub fn create(path: &Path, compression: Compression) -> Result<Self, InputError> {
        let file = std::fs::File::create(path).map_err(|source| InputError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        LogWriter::new(BufWriter::new(file), compression)
    }
}

impl<W: Write + Seek> LogWriter<W> {
    /// Starts a log on `w`.
    pub fn new(w: W, compression: Compression) -> Result<Self, InputError> {
        let compression = match compression {
            Compression::Zstd => Some(mcap::Compression::Zstd),
            Compression::Lz4 => Some(mcap::Compression::Lz4),
            Compression::None => None,
        };
        let inner = mcap::WriteOptions::new()
            .compression(compression)
            .profile("ros2")
            .library(concat!("latentam ", env!("CARGO_PKG_VERSION")))
            .create(w)
            .map_err(write_error)?;
        Ok(LogWriter {
            inner,
            schemas: HashMap::new(),
            channels: HashMap::new(),
            sequence: 0,
        })
    }

    fn channel<'a, M: RosMessage<'a>>(&mut self, topic: &str) -> Result<u16, InputError> {
        if let Some(&(id, ty)) = self.channels.get(topic) {
            if ty != M::TYPE_NAME {
                return Err(InputError::Write(format!(
                    "topic {topic} already carries {ty}, cannot also write {}",
                    M::TYPE_NAME
                )));
            }
            return Ok(id);
        }
        let schema = match self.schemas.get(M::TYPE_NAME) {
            Some(&id) => id,
            None => {
                let text = schema_text(M::TYPE_NAME).expect("every RosMessage has a schema");
                let id = self
                    .inner
                    .add_schema(M::TYPE_NAME, "ros2msg", text.as_bytes())
                    .map_err(write_error)?;
                self.schemas.insert(M::TYPE_NAME, id);
                id
            }
        };
        let id = self
            .inner
            .add_channel(schema, topic, "cdr", &BTreeMap::new())
            .map_err(write_error)?;
        self.channels.insert(topic.to_string(), (id, M::TYPE_NAME));
        Ok(id)
    }

    /// Writes one message with log and publish time `log_time_ns`.
    pub fn write<'a, M: RosMessage<'a>>(
        &mut self,
        topic: &str,
        log_time_ns: u64,
        msg: &M,
    ) -> Result<(), InputError> {
        self.write_raw::<M>(topic, log_time_ns, &msg.encode())
    }

    /// Writes an already serialized message of type `M`.
    pub fn write_raw<'a, M: RosMessage<'a>>(
        &mut self,
        topic: &str,
        log_time_ns: u64,
        data: &[u8],
    ) -> Result<(), InputError> {
        let channel_id = self.channel::<M>(topic)?;
        self.sequence = self.sequence.wrapping_add(1);
        self.inner
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id,
                    sequence: self.sequence,
                    log_time: log_time_ns,
                    publish_time: log_time_ns,
                },
                data,
            )
            .map_err(write_error)
    }

    /// Adds a metadata record.
    pub fn metadata(
        &mut self,
        name: &str,
        values: BTreeMap<String, String>,
    ) -> Result<(), InputError> {
        self.inner
            .write_metadata(&mcap::records::Metadata {
                name: name.to_string(),
                metadata: values,
            })
            .map_err(write_error)
    }

    /// Writes the summary and footer and flushes.
    pub fn finish(mut self) -> Result<W, InputError> {
        self.inner.finish().map_err(write_error)?;
        let mut w = self.inner.into_inner();
        w.flush().map_err(write_error)?;
        Ok(w)
    }
}
