//! Reading MCAP logs: one file or a rosbag2 directory of split files,
//! memory-mapped, read through the summary's chunk index by topic and time
//! (or scanned linearly when a file has no summary, e.g. a recording that
//! was cut off). Only the chunks being read are decompressed, so a log far
//! larger than RAM streams.
//!
//! Every chunk that carries a CRC is checked against it, on both paths,
//! before any of its messages is handed out: a flipped bit in an image
//! would otherwise be mapped as if it were what the camera saw.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use mcap::sans_io::indexed_reader::{IndexedReadEvent, IndexedReader, IndexedReaderOptions};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::McapError;

use super::InputError;

mod chunks;
mod reader;

use chunks::*;
pub use reader::MessageReader;
use reader::*;

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
    fn admits(&self, topic: &str, log_time: u64) -> bool {
        self.topics
            .as_ref()
            .is_none_or(|t| t.iter().any(|x| x == topic))
            && self.start_ns.is_none_or(|s| log_time >= s)
            && self.end_ns.is_none_or(|e| log_time < e)
    }
}

struct LogFile {
    path: PathBuf,
    map: memmap2::Mmap,
    summary: Option<mcap::Summary>,
    /// What the indexed reader is given instead of `summary`, present with
    /// it: see [`PlainChunks`].
    plain: Option<PlainChunks>,
    /// Why the summary could not be used, when it could not.
    summary_problem: Option<String>,
    /// Channels found by scanning a file without a summary (scanned once),
    /// and the error that stopped the scan, if one did.
    scanned: std::sync::OnceLock<(Vec<Channel>, Option<InputError>)>,
}

/// An opened MCAP log.
///
/// ```no_run
/// use latentam_io::{McapLog, ReadFilter};
///
/// let log = McapLog::open("run.mcap".as_ref())?;
/// for c in log.channels() {
///     println!("{} ({})", c.topic, c.schema_name);
/// }
/// let mut reader = log.reader(ReadFilter::default());
/// while let Some(done) = reader.next_with(|m| m.data.len()) {
///     println!("{} bytes", done?);
/// }
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone)]
pub struct McapLog {
    files: Arc<Vec<LogFile>>,
}

/// Natural order of file names, so `run_10.mcap` follows `run_9.mcap`.
fn natural_key(name: &str) -> Vec<(String, u64)> {
    let mut key = Vec::new();
    let mut text = String::new();
    let mut digits = String::new();
    for ch in name.chars() {
        if ch.is_ascii_digit() {
            digits.push(ch);
        } else {
            if !digits.is_empty() {
                key.push((
                    std::mem::take(&mut text),
                    digits.parse().unwrap_or(u64::MAX),
                ));
                digits.clear();
            }
            text.push(ch);
        }
    }
    key.push((text, digits.parse().unwrap_or(0)));
    key
}

impl McapLog {
    /// Opens a `.mcap` file, or a directory holding a rosbag2 recording
    /// split into several `.mcap` files (read in time order).
    pub fn open(path: &Path) -> Result<Self, InputError> {
        let io = |source| InputError::Io {
            path: path.to_path_buf(),
            source,
        };
        let meta = std::fs::metadata(path).map_err(io)?;
        let mut paths = if meta.is_dir() {
            let mut v: Vec<PathBuf> = std::fs::read_dir(path)
                .map_err(io)?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
                .collect();
            v.sort_by_key(|p| natural_key(&p.file_name().unwrap_or_default().to_string_lossy()));
            if v.is_empty() {
                return Err(InputError::Log {
                    path: path.to_path_buf(),
                    reason: "directory holds no .mcap files".into(),
                });
            }
            v
        } else {
            vec![path.to_path_buf()]
        };
        let mut files = Vec::with_capacity(paths.len());
        for p in paths.drain(..) {
            files.push(LogFile::open(p)?);
        }
        // Split files are consecutive in time; order by first message when
        // the summaries say, keeping name order otherwise.
        files.sort_by_key(|f| {
            f.summary
                .as_ref()
                .and_then(|s| s.stats.as_ref())
                .map_or(u64::MAX, |s| s.message_start_time)
        });
        Ok(McapLog {
            files: Arc::new(files),
        })
    }

    /// The files read, in order.
    pub fn files(&self) -> Vec<&Path> {
        self.files.iter().map(|f| f.path.as_path()).collect()
    }

    /// Files that have no usable summary and will be scanned linearly, with
    /// the reason.
    pub fn unindexed_files(&self) -> Vec<(&Path, &str)> {
        self.files
            .iter()
            .filter_map(|f| f.summary_problem.as_deref().map(|p| (f.path.as_path(), p)))
            .collect()
    }

    /// The first error that stopped the scan of a file without a summary
    /// (run by [`McapLog::channels`]): damage before a topic's first
    /// message hides that topic, and this says why.
    pub fn scan_problem(&self) -> Option<&InputError> {
        self.files
            .iter()
            .filter(|f| f.summary.is_none())
            .find_map(|f| f.scanned_channels().1.as_ref())
    }

    /// Every channel named in the summaries (or, for files without one,
    /// found by scanning), one entry per topic.
    pub fn channels(&self) -> Vec<Channel> {
        let mut out: BTreeMap<String, Channel> = BTreeMap::new();
        for f in self.files.iter() {
            match &f.summary {
                Some(s) => {
                    for c in s.channels.values() {
                        out.entry(c.topic.clone()).or_insert_with(|| channel_of(c));
                    }
                }
                None => {
                    for c in &f.scanned_channels().0 {
                        out.entry(c.topic.clone()).or_insert_with(|| c.clone());
                    }
                }
            }
        }
        out.into_values().collect()
    }

    /// First and last message log times (nanoseconds) according to the
    /// summaries, `None` when a file has no statistics.
    pub fn time_range(&self) -> Option<(u64, u64)> {
        let mut range: Option<(u64, u64)> = None;
        for f in self.files.iter() {
            let st = f.summary.as_ref()?.stats.as_ref()?;
            if st.message_count == 0 {
                continue;
            }
            let (a, b) = (st.message_start_time, st.message_end_time);
            range = Some(range.map_or((a, b), |(x, y)| (x.min(a), y.max(b))));
        }
        range
    }

    /// Number of messages on `topic` according to the summaries, `None`
    /// when a file has no statistics (or the counts, being corrupt,
    /// overflow).
    pub fn message_count(&self, topic: &str) -> Option<u64> {
        let mut total: u64 = 0;
        for f in self.files.iter() {
            let s = f.summary.as_ref()?;
            let stats = s.stats.as_ref()?;
            for (id, c) in &s.channels {
                if c.topic == topic {
                    let n = stats.channel_message_counts.get(id).copied().unwrap_or(0);
                    total = total.checked_add(n)?;
                }
            }
        }
        Some(total)
    }

    /// Total messages in the log according to the summaries, `None` when a
    /// file has no statistics (or the counts, being corrupt, overflow).
    pub fn total_messages(&self) -> Option<u64> {
        self.files.iter().try_fold(0u64, |total, f| {
            total.checked_add(f.summary.as_ref()?.stats.as_ref()?.message_count)
        })
    }

    /// The log's metadata records (name → key/value map), e.g. the
    /// `latentam` record converters write.
    pub fn metadata(&self) -> Result<Vec<(String, Metadata)>, InputError> {
        let mut out = Vec::new();
        for f in self.files.iter() {
            let Some(s) = &f.summary else { continue };
            for index in &s.metadata_indexes {
                let m = mcap::read::metadata(&f.map, index).map_err(|e| f.error(e))?;
                out.push((m.name, m.metadata));
            }
        }
        Ok(out)
    }

    /// A reader over the messages `filter` admits: in log-time order within
    /// each file, files one after the other.
    pub fn reader(&self, filter: ReadFilter) -> MessageReader {
        MessageReader {
            log: self.clone(),
            filter,
            file: 0,
            current: None,
        }
    }
}

fn channel_of(c: &mcap::Channel<'_>) -> Channel {
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

impl LogFile {
    fn open(path: PathBuf) -> Result<Self, InputError> {
        let file = super::open_input(&path).map_err(|source| InputError::Io {
            path: path.clone(),
            source,
        })?;
        // SAFETY: the map is read-only; if another process truncates the
        // file while it is mapped, reads fault (SIGBUS) rather than return
        // wrong data. Logs being read are not expected to be rewritten.
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|source| InputError::Io {
            path: path.clone(),
            source,
        })?;
        let _ = map.advise(memmap2::Advice::Sequential);
        if map.len() < 8 || &map[..8] != mcap::MAGIC {
            return Err(InputError::Log {
                path,
                reason: "not an MCAP file (no MCAP magic at its start)".into(),
            });
        }
        let (summary, summary_problem) = match mcap::Summary::read(&map) {
            Ok(Some(s)) if !s.chunk_indexes.is_empty() || s.stats.is_some() => (Some(s), None),
            Ok(Some(_)) => (None, Some("the summary has no chunk index".to_string())),
            Ok(None) => (None, Some("the file has no summary section".to_string())),
            Err(e) => (
                None,
                Some(format!(
                    "the summary cannot be read ({e}); the file may be truncated"
                )),
            ),
        };
        if let Some(p) = &summary_problem {
            log::warn!("{}: {p}; reading it linearly", path.display());
        }
        let plain = summary.as_ref().map(PlainChunks::new);
        Ok(LogFile {
            path,
            map,
            summary,
            plain,
            summary_problem,
            scanned: std::sync::OnceLock::new(),
        })
    }

    /// The channels of a file without a summary, found by reading it once
    /// (a damaged file still lists those before the damage).
    fn scanned_channels(&self) -> &(Vec<Channel>, Option<InputError>) {
        self.scanned.get_or_init(|| {
            let filter = ReadFilter::default();
            let mut reader = FileReader::linear(self, &filter);
            let mut problem = None;
            while let Some(r) = reader.next_with(self, &filter, |_| ()) {
                if let Err(e) = r {
                    problem = Some(e);
                    break;
                }
            }
            let mut v: Vec<Channel> = reader
                .channels
                .into_values()
                .map(|c| (*c).clone())
                .collect();
            v.sort_by(|a, b| a.topic.cmp(&b.topic));
            (v, problem)
        })
    }

    fn error(&self, e: impl std::fmt::Display) -> InputError {
        InputError::Log {
            path: self.path.clone(),
            reason: e.to_string(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_files_sort_naturally() {
        let mut names = vec!["run_10.mcap", "run_2.mcap", "run_1.mcap"];
        names.sort_by_key(|n| natural_key(n));
        assert_eq!(names, ["run_1.mcap", "run_2.mcap", "run_10.mcap"]);
    }
}
