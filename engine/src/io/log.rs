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

/// Largest record (chunk or message) accepted, so a corrupt length field
/// cannot make the reader buffer the rest of a huge file.
pub const MAX_RECORD_BYTES: usize = 1 << 30;

/// A topic of the log and what its messages are.
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
pub type Metadata = BTreeMap<String, String>;

/// Which messages to read.
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
/// use latentam::io::{McapLog, ReadFilter};
///
/// let log = McapLog::open("run.mcap".as_ref())?;
/// for c in log.channels() {
///     println!("{} ({})", c.topic, c.schema_name);
/// }
/// let mut reader = log.reader(ReadFilter::default());
/// while let Some(done) = reader.next_with(|m| m.data.len()) {
///     println!("{} bytes", done?);
/// }
/// # Ok::<(), latentam::io::InputError>(())
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

/// The summary as the indexed reader is given it, with every chunk
/// described as uncompressed.
///
/// `IndexedReader` decompresses what it is handed but never checks a
/// chunk's CRC (the CRC is in the chunk record's header, which it does not
/// read). So each chunk is decompressed and checked here first (see
/// [`unpack_chunk`]), and the reader is handed the plain records;
/// describing them as uncompressed keeps it from decompressing a second
/// time.
struct PlainChunks {
    summary: mcap::Summary,
    /// The file's own chunk index of each chunk, by the data offset the
    /// reader asks for.
    original: HashMap<u64, mcap::records::ChunkIndex>,
}

impl PlainChunks {
    fn new(summary: &mcap::Summary) -> Self {
        let mut plain = summary.clone();
        let mut original = HashMap::new();
        for index in &mut plain.chunk_indexes {
            let file_index = index.clone();
            index.compression.clear();
            index.compressed_size = index.uncompressed_size;
            // An offset that overflows is refused by the reader itself.
            if let Ok(offset) = index.compressed_data_offset() {
                original.insert(offset, file_index);
            }
        }
        PlainChunks {
            summary: plain,
            original,
        }
    }
}

/// Why a chunk could not be unpacked.
enum ChunkProblem {
    /// The index points past the end of the file.
    Truncated,
    /// The index points at something other than a chunk record.
    NotAChunk,
    /// The chunk's records do not match its CRC.
    Crc { saved: u32, calculated: u32 },
    /// Anything else the chunk record gets wrong.
    Corrupt(String),
}

impl From<McapError> for ChunkProblem {
    fn from(e: McapError) -> Self {
        match e {
            McapError::BadChunkCrc { saved, calculated } => ChunkProblem::Crc { saved, calculated },
            e => ChunkProblem::Corrupt(e.to_string()),
        }
    }
}

/// The records of the chunk `index` describes, checked against the
/// chunk's CRC (when it has one) before anything reads them: for an
/// uncompressed chunk, the file's own bytes; for a compressed one,
/// decompressed into `scratch`.
fn unpack_chunk<'a>(
    map: &'a [u8],
    index: &mcap::records::ChunkIndex,
    scratch: &'a mut Vec<u8>,
) -> Result<&'a [u8], ChunkProblem> {
    let record = usize::try_from(index.chunk_start_offset)
        .ok()
        .zip(usize::try_from(index.chunk_length).ok())
        .and_then(|(start, len)| map.get(start..start.checked_add(len)?))
        .ok_or(ChunkProblem::Truncated)?;
    if record.first() != Some(&mcap::records::op::CHUNK) {
        return Err(ChunkProblem::NotAChunk);
    }
    // The chunk header after the opcode and record length: start and end
    // times, uncompressed size, CRC, compression (a length-prefixed
    // string), compressed size, then the data.
    let field = |at: usize, n: usize| record.get(9 + at..9 + at + n);
    let le_u64 = |b: &[u8]| u64::from_le_bytes(b.try_into().expect("8 bytes"));
    let le_u32 = |b: &[u8]| u32::from_le_bytes(b.try_into().expect("4 bytes"));
    let header = field(16, 24).ok_or(ChunkProblem::Truncated)?;
    let (uncompressed, saved, compression_len) = (
        le_u64(&header[..8]),
        le_u32(&header[8..12]),
        le_u32(&header[12..16]),
    );
    if compression_len == 0 {
        // Uncompressed: the data is the records, hashed where it lies.
        let size = le_u64(&header[16..24]);
        let data = usize::try_from(size)
            .ok()
            .and_then(|n| field(40, n))
            .ok_or_else(|| {
                ChunkProblem::Corrupt(format!("its {size} bytes of data overrun the record"))
            })?;
        if size != uncompressed {
            return Err(ChunkProblem::Corrupt(format!(
                "uncompressed, yet {size} bytes of data for {uncompressed} bytes of records"
            )));
        }
        if saved != 0 {
            let calculated = crc32fast::hash(data);
            if calculated != saved {
                return Err(ChunkProblem::Crc { saved, calculated });
            }
        }
        return Ok(data);
    }
    // Compressed: a linear reader over just this record decompresses it,
    // checks the CRC before yielding the first record (and refuses sizes
    // beyond the limit before allocating), then yields the records, which
    // are framed again here as they were before compression.
    let options = LinearReaderOptions::default()
        .with_skip_start_magic(true)
        .with_skip_end_magic(true)
        .with_prevalidate_chunk_crcs(true)
        .with_record_length_limit(MAX_RECORD_BYTES);
    let mut reader = LinearReader::new_with_options(options);
    let mut rest = record;
    scratch.clear();
    while let Some(event) = reader.next_event() {
        match event? {
            LinearReadEvent::ReadRequest(need) => {
                let n = need.min(rest.len());
                reader.insert(n).copy_from_slice(&rest[..n]);
                reader.notify_read(n);
                rest = &rest[n..];
            }
            LinearReadEvent::Record { data, opcode } => {
                scratch.push(opcode);
                scratch.extend_from_slice(&(data.len() as u64).to_le_bytes());
                scratch.extend_from_slice(data);
            }
        }
    }
    Ok(scratch)
}

fn crc_mismatch(at: u64, saved: u32, calculated: u32) -> String {
    format!(
        "chunk at byte {at} is corrupt: CRC mismatch (the chunk says {saved:08x}, \
         its records hash to {calculated:08x})"
    )
}

/// The message for a chunk at byte `at` that [`unpack_chunk`] refused.
fn chunk_problem(at: u64, map: &[u8], problem: ChunkProblem) -> String {
    match problem {
        ChunkProblem::Truncated => format!(
            "chunk at byte {at} runs past the end of the file ({} bytes); \
             the file is truncated",
            map.len()
        ),
        ChunkProblem::NotAChunk => {
            format!("the index points at byte {at}, which is not a chunk record")
        }
        ChunkProblem::Crc { saved, calculated } => crc_mismatch(at, saved, calculated),
        ChunkProblem::Corrupt(why) => format!("chunk at byte {at} is corrupt: {why}"),
    }
}

/// The start of the last chunk record that begins before byte `pos`,
/// stepping over the top-level records from the start of the file (only
/// done to name the chunk in an error: the linear reader does not say
/// where the records it reports on began).
fn chunk_before(map: &[u8], pos: usize) -> Option<usize> {
    let mut at = mcap::MAGIC.len();
    let mut found = None;
    while at < pos {
        let (Some(&opcode), Some(len)) = (map.get(at), map.get(at + 1..at + 9)) else {
            break;
        };
        if opcode == mcap::records::op::CHUNK {
            found = Some(at);
        }
        // Slices of 8 bytes by the range above.
        let len = u64::from_le_bytes(len.try_into().expect("8 bytes"));
        match usize::try_from(len)
            .ok()
            .and_then(|n| (at + 9).checked_add(n))
        {
            Some(next) => at = next,
            None => break,
        }
    }
    found
}

/// Reads messages one at a time; see [`McapLog::reader`].
pub struct MessageReader {
    log: McapLog,
    filter: ReadFilter,
    file: usize,
    current: Option<FileReader>,
}

impl MessageReader {
    /// Reads the next admitted message and passes it to `f`; `None` at the
    /// end of the log. The message borrows the reader's buffers, so it only
    /// lives for the call.
    pub fn next_with<R>(
        &mut self,
        mut f: impl FnMut(RawMessage<'_>) -> R,
    ) -> Option<Result<R, InputError>> {
        loop {
            let file = self.log.files.get(self.file)?;
            let reader = match &mut self.current {
                Some(r) => r,
                None => self.current.insert(FileReader::new(file, &self.filter)),
            };
            // `f` is called at most once per iteration; the result is moved
            // out through `out` so the borrow of `reader` ends here.
            let mut out = None;
            match reader.next_with(file, &self.filter, |m| out = Some(f(m))) {
                // `FileReader::next_with` returns `Some(Ok(()))` only right
                // after calling the callback, which set `out`.
                Some(Ok(())) => return Some(Ok(out.expect("callback ran"))),
                Some(Err(e)) => {
                    // Give up on this file after an error.
                    self.current = None;
                    self.file += 1;
                    return Some(Err(e));
                }
                None => {
                    self.current = None;
                    self.file += 1;
                }
            }
        }
    }
}

enum Source {
    Indexed {
        reader: Box<IndexedReader>,
        /// Where compressed chunks are decompressed to be checked (kept
        /// to reuse its allocation).
        records: Vec<u8>,
    },
    Linear {
        reader: Box<LinearReader>,
        pos: usize,
    },
    Failed(Option<InputError>),
}

struct FileReader {
    source: Source,
    channels: HashMap<u16, Arc<Channel>>,
    schemas: HashMap<u16, (String, String)>,
}

impl FileReader {
    fn new(file: &LogFile, filter: &ReadFilter) -> Self {
        match (&file.summary, &file.plain) {
            (Some(summary), Some(plain)) => {
                let mut options =
                    IndexedReaderOptions::new().with_record_length_limit(MAX_RECORD_BYTES);
                if let Some(topics) = &filter.topics {
                    options = options.include_topics(topics.iter().cloned());
                }
                if let Some(s) = filter.start_ns {
                    options = options.starting_at(s);
                }
                if let Some(e) = filter.end_ns {
                    options = options.ending_before(e);
                }
                let channels = summary
                    .channels
                    .iter()
                    .map(|(id, c)| (*id, Arc::new(channel_of(c))))
                    .collect();
                let source = match IndexedReader::new_with_options(&plain.summary, options) {
                    Ok(r) => Source::Indexed {
                        reader: Box::new(r),
                        records: Vec::new(),
                    },
                    Err(e) => Source::Failed(Some(file.error(e))),
                };
                FileReader {
                    source,
                    channels,
                    schemas: HashMap::new(),
                }
            }
            _ => Self::linear(file, filter),
        }
    }

    fn linear(_file: &LogFile, _filter: &ReadFilter) -> Self {
        // Checking a chunk's CRC only after its last record (the reader's
        // `validate_chunk_crcs`) would hand out the records before it.
        let options = LinearReaderOptions::default()
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(MAX_RECORD_BYTES);
        FileReader {
            source: Source::Linear {
                reader: Box::new(LinearReader::new_with_options(options)),
                pos: 0,
            },
            channels: HashMap::new(),
            schemas: HashMap::new(),
        }
    }

    /// Calls `f` with the next admitted message: `Some(Ok(()))` after a
    /// call, `None` at the end of the file.
    fn next_with(
        &mut self,
        file: &LogFile,
        filter: &ReadFilter,
        mut f: impl FnMut(RawMessage<'_>),
    ) -> Option<Result<(), InputError>> {
        let FileReader {
            source,
            channels,
            schemas,
        } = self;
        match source {
            Source::Failed(e) => e.take().map(Err),
            Source::Indexed { reader, records } => loop {
                match reader.next_event()? {
                    Err(e) => return Some(Err(file.error(e))),
                    Ok(IndexedReadEvent::ReadChunkRequest { offset, .. }) => {
                        // `plain` exists whenever the reader is indexed.
                        let Some(index) = file.plain.as_ref().and_then(|p| p.original.get(&offset))
                        else {
                            return Some(Err(file.error(format!(
                                "the index asked for an unknown chunk (data at byte {offset})"
                            ))));
                        };
                        let at = index.chunk_start_offset;
                        let plain = match unpack_chunk(&file.map, index, records) {
                            Ok(plain) => plain,
                            Err(e) => {
                                return Some(Err(file.error(chunk_problem(at, &file.map, e))))
                            }
                        };
                        if let Err(e) = reader.insert_chunk_record_data(offset, plain) {
                            return Some(Err(
                                file.error(format!("chunk at byte {at} is corrupt: {e}"))
                            ));
                        }
                    }
                    Ok(IndexedReadEvent::Message { header, data }) => {
                        let Some(channel) = channels.get(&header.channel_id) else {
                            return Some(Err(file.error(format!(
                                "message on unknown channel id {}",
                                header.channel_id
                            ))));
                        };
                        // The indexed reader reads every topic when none of
                        // the requested ones is in the file, so the filter
                        // is applied here too.
                        if !filter.admits(&channel.topic, header.log_time) {
                            continue;
                        }
                        f(RawMessage {
                            channel,
                            log_time: header.log_time,
                            data,
                        });
                        return Some(Ok(()));
                    }
                }
            },
            Source::Linear { reader, pos } => loop {
                match reader.next_event()? {
                    Err(McapError::BadChunkCrc { saved, calculated }) => {
                        let reason = match chunk_before(&file.map, *pos) {
                            Some(at) => crc_mismatch(at as u64, saved, calculated),
                            None => format!(
                                "a chunk before byte {pos} is corrupt: {}",
                                McapError::BadChunkCrc { saved, calculated }
                            ),
                        };
                        *source = Source::Failed(None);
                        return Some(Err(file.error(reason)));
                    }
                    Err(e) => {
                        let err = file.error(format!(
                            "unreadable near byte {pos} of {}: {e} (truncated or corrupt file)",
                            file.map.len()
                        ));
                        *source = Source::Failed(None);
                        return Some(Err(err));
                    }
                    Ok(LinearReadEvent::ReadRequest(need)) => {
                        // `pos` never passes the end: it only grows by `n`,
                        // which is at most what is left.
                        let n = need.min(file.map.len() - *pos);
                        reader.insert(n).copy_from_slice(&file.map[*pos..*pos + n]);
                        reader.notify_read(n);
                        *pos += n;
                    }
                    Ok(LinearReadEvent::Record { data, opcode }) => {
                        let record = match mcap::parse_record(opcode, data) {
                            Ok(r) => r,
                            Err(e) => {
                                let err =
                                    file.error(format!("corrupt record near byte {pos}: {e}"));
                                *source = Source::Failed(None);
                                return Some(Err(err));
                            }
                        };
                        match record {
                            mcap::records::Record::Schema { header, .. } => {
                                schemas.insert(header.id, (header.name, header.encoding));
                            }
                            mcap::records::Record::Channel(c) => {
                                let (schema_name, schema_encoding) =
                                    schemas.get(&c.schema_id).cloned().unwrap_or_default();
                                channels.insert(
                                    c.id,
                                    Arc::new(Channel {
                                        topic: c.topic,
                                        schema_name,
                                        schema_encoding,
                                        message_encoding: c.message_encoding,
                                    }),
                                );
                            }
                            mcap::records::Record::Message { header, data } => {
                                let Some(channel) = channels.get(&header.channel_id) else {
                                    let err = file.error(format!(
                                        "message on channel id {} before its channel record",
                                        header.channel_id
                                    ));
                                    *source = Source::Failed(None);
                                    return Some(Err(err));
                                };
                                if filter.admits(&channel.topic, header.log_time) {
                                    f(RawMessage {
                                        channel,
                                        log_time: header.log_time,
                                        data: &data,
                                    });
                                    return Some(Ok(()));
                                }
                            }
                            _ => {}
                        }
                    }
                }
            },
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
