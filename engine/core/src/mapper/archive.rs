//! The file a saved map lives in: one safetensors file (named tensors plus
//! string metadata), tagged with a format name and version, written
//! atomically (temporary file, fsync, rename, fsync of the directory) so a
//! crash leaves either the old file or the new one.

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use safetensors::Dtype;

use latentam_base::{Error, Result};

/// Format name stored in every archive's metadata.
pub const FORMAT: &str = "latentam-map";
/// Version this build writes and reads: its archives must carry their
/// checksum. (It is otherwise laid out as [`LEGACY_VERSION`].)
pub const VERSION: u32 = 2;
/// The version before the checksum was required, of maps and decoders
/// alike: read too, and checked when it carries a checksum, since the
/// files written before there was one have none. A file that names this
/// version says it is such a file; one of the current version without a
/// checksum was edited and is refused.
pub const LEGACY_VERSION: u32 = 1;

/// Element types an archive stores.
pub(crate) trait Element: bytemuck::Pod {
    const DTYPE: Dtype;
}

macro_rules! element {
    ($t:ty, $d:ident) => {
        impl Element for $t {
            const DTYPE: Dtype = Dtype::$d;
        }
    };
}
element!(f32, F32);
element!(f64, F64);
element!(i32, I32);
element!(i64, I64);
element!(u8, U8);
element!(u16, U16);
element!(u32, U32);

/// Writes a tensor's bytes into an archive, in order, as its producer
/// reads them from wherever they live (see [`ArchiveWriter::stream`]).
pub(crate) struct Sink<'w> {
    out: &'w mut dyn std::io::Write,
    crc: &'w mut crc32fast::Hasher,
    written: u64,
    /// Names the output in errors.
    path: &'w Path,
}

impl Sink<'_> {
    /// Appends `bytes` to the tensor.
    pub fn put(&mut self, bytes: &[u8]) -> Result<()> {
        self.crc.update(bytes);
        self.written += bytes.len() as u64;
        self.out
            .write_all(bytes)
            .map_err(|e| io_error(self.path, "writing", e))
    }
}

/// Writes a streamed tensor's bytes into a [`Sink`].
type Producer<'a> = Box<dyn FnOnce(&mut Sink<'_>) -> Result<()> + 'a>;

/// A tensor's bytes: copied in, borrowed, or produced while the archive
/// is written, so that a tensor larger than memory (the global map of an
/// out-of-core run) goes from its source to the file without being
/// gathered first.
enum TensorData<'a> {
    Held(Vec<u8>),
    Borrowed(&'a [u8]),
    Streamed(Producer<'a>),
}

struct PendingTensor<'a> {
    name: String,
    dtype: Dtype,
    shape: Vec<usize>,
    /// The byte size its dtype and shape give (`None` on overflow).
    bytes: Option<usize>,
    data: TensorData<'a>,
}

/// Collects tensors and metadata, then writes the archive in one pass:
/// the header first (its offsets come from the shapes), then every tensor
/// in name order, the checksum computed on the way and written into the
/// header at the end. Memory stays that of the tensors held, whatever the
/// size of the streamed ones.
#[derive(Default)]
pub(crate) struct ArchiveWriter<'a> {
    tensors: Vec<PendingTensor<'a>>,
    meta: HashMap<String, String>,
    /// Format name and version; unset: the map's.
    format: Option<(&'static str, u32)>,
}

impl<'a> ArchiveWriter<'a> {
    /// An archive of another format than the saved map.
    pub fn with_format(name: &'static str, version: u32) -> Self {
        ArchiveWriter {
            format: Some((name, version)),
            ..Default::default()
        }
    }

    pub fn meta(&mut self, key: &str, value: impl ToString) {
        self.meta.insert(key.to_string(), value.to_string());
    }

    fn push(&mut self, name: &str, dtype: Dtype, shape: &[usize], data: TensorData<'a>) {
        let bytes = shape
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .and_then(|n| n.checked_mul(dtype.bitsize()))
            .map(|bits| bits.div_ceil(8));
        self.tensors.push(PendingTensor {
            name: name.to_string(),
            dtype,
            shape: shape.to_vec(),
            bytes,
            data,
        });
    }

    /// Adds `data` (copied) as a tensor of `shape` (row-major; the product
    /// of `shape` must equal `data.len()`, or writing fails).
    pub fn tensor<T: Element>(&mut self, name: &str, shape: &[usize], data: &[T]) {
        let bytes = bytemuck::cast_slice(data).to_vec();
        self.push(name, T::DTYPE, shape, TensorData::Held(bytes));
    }

    /// [`ArchiveWriter::tensor`] without the copy: `data` is read when the
    /// archive is written.
    pub fn tensor_ref<T: Element>(&mut self, name: &str, shape: &[usize], data: &'a [T]) {
        let bytes = bytemuck::cast_slice(data);
        self.push(name, T::DTYPE, shape, TensorData::Borrowed(bytes));
    }

    /// Adds raw rows: `rows` × `row_bytes` bytes (checked like
    /// [`ArchiveWriter::tensor`]).
    pub fn bytes(&mut self, name: &str, rows: usize, row_bytes: usize, data: &'a [u8]) {
        self.push(
            name,
            Dtype::U8,
            &[rows, row_bytes],
            TensorData::Borrowed(data),
        );
    }

    /// A tensor of `T` and `shape` whose bytes `produce` writes into the
    /// archive when it is written, exactly as many as the shape gives
    /// (fewer or more is an error, and no file is left).
    pub fn stream<T: Element>(
        &mut self,
        name: &str,
        shape: &[usize],
        produce: impl FnOnce(&mut Sink<'_>) -> Result<()> + 'a,
    ) {
        self.push(
            name,
            T::DTYPE,
            shape,
            TensorData::Streamed(Box::new(produce)),
        );
    }

    /// The archive's bytes.
    pub fn into_bytes(self) -> Result<Vec<u8>> {
        let mut out = std::io::Cursor::new(Vec::new());
        self.write_into(&mut out, Path::new("the archive"))?;
        Ok(out.into_inner())
    }

    /// Writes the archive to `path`, replaced whole (through a partial
    /// file, synced and renamed: a crash leaves the old file or the new).
    pub fn write_file(self, path: &Path) -> Result<()> {
        latentam_base::files::write_atomically_with(path, |out| self.write_into(out, path))
    }

    /// The header, then the tensors in name order; the checksum goes into
    /// the header last (a fixed-width value, so nothing moves).
    fn write_into<W: std::io::Write + std::io::Seek>(
        mut self,
        out: &mut W,
        path: &Path,
    ) -> Result<()> {
        use safetensors::tensor::TensorInfo;
        use serde_json::Value;
        use std::collections::BTreeMap;
        let ours = |why: String| Error::bad_input("writing an archive", why);
        let (format, version) = self.format.unwrap_or((FORMAT, VERSION));
        self.meta.insert("format".into(), format.into());
        self.meta.insert("version".into(), version.to_string());
        self.meta
            .insert(CHECKSUM_KEY.into(), PENDING_CHECKSUM.into());
        self.tensors.sort_by(|a, b| a.name.cmp(&b.name));
        if let Some(w) = self.tensors.windows(2).find(|w| w[0].name == w[1].name) {
            return Err(ours(format!("tensor `{}` added twice", w[0].name)));
        }

        // Sorted explicitly (BTreeMap), so the same state gives the same
        // bytes in every process.
        let mut header: BTreeMap<String, Value> = BTreeMap::new();
        let mut at = 0usize;
        for t in &self.tensors {
            let size = t.bytes.ok_or_else(|| {
                ours(format!(
                    "tensor `{}` of shape {:?} is too large",
                    t.name, t.shape
                ))
            })?;
            let info = TensorInfo {
                dtype: t.dtype,
                shape: t.shape.clone(),
                data_offsets: (at, at + size),
            };
            let info = serde_json::to_value(info).map_err(|e| ours(e.to_string()))?;
            header.insert(t.name.clone(), info);
            at += size;
        }
        let meta: BTreeMap<&String, &String> = self.meta.iter().collect();
        header.insert(
            "__metadata__".into(),
            serde_json::to_value(meta).map_err(|e| ours(e.to_string()))?,
        );
        let mut text = serde_json::to_vec(&header).map_err(|e| ours(e.to_string()))?;
        // Padded with spaces to a multiple of 8, as safetensors pads it.
        text.resize(text.len().next_multiple_of(8), b' ');
        // JSON escapes the quotes inside values, so this is the entry.
        let pending = format!("\"{CHECKSUM_KEY}\":\"{PENDING_CHECKSUM}\"");
        let crc_at = text
            .windows(pending.len())
            .position(|w| w == pending.as_bytes())
            .ok_or_else(|| ours("the header lost its checksum entry".into()))?
            + format!("\"{CHECKSUM_KEY}\":\"").len();

        let io = |e| io_error(path, "writing", e);
        out.write_all(&(text.len() as u64).to_le_bytes())
            .and_then(|_| out.write_all(&text))
            .map_err(io)?;
        let mut hasher = meta_hasher(self.meta.iter().map(|(k, v)| (k.as_str(), v.as_str())));
        for t in self.tensors {
            let size = t.bytes.unwrap_or(0);
            field_start(&mut hasher, t.name.as_bytes());
            hasher.update(&(size as u64).to_le_bytes());
            let mut sink = Sink {
                out: &mut *out,
                crc: &mut hasher,
                written: 0,
                path,
            };
            match t.data {
                TensorData::Held(bytes) => sink.put(&bytes)?,
                TensorData::Borrowed(bytes) => sink.put(bytes)?,
                TensorData::Streamed(produce) => produce(&mut sink)?,
            }
            if sink.written != size as u64 {
                return Err(ours(format!(
                    "tensor `{}` of shape {:?} came with {} bytes, not {size}",
                    t.name, t.shape, sink.written
                )));
            }
        }
        let sum = format!("{:08x}", hasher.finalize());
        let end = out.stream_position().map_err(io)?;
        out.seek(std::io::SeekFrom::Start(8 + crc_at as u64))
            .and_then(|_| out.write_all(sum.as_bytes()))
            .and_then(|_| out.seek(std::io::SeekFrom::Start(end)))
            .map_err(io)?;
        Ok(())
    }
}

/// What the header holds for the checksum until the tensors are written:
/// as wide as any checksum, so replacing it moves nothing.
const PENDING_CHECKSUM: &str = "00000000";

/// The metadata part of [`checksum`]: a hasher that has taken every entry
/// but the checksum itself, in key order, for the tensors to continue.
fn meta_hasher<'b>(meta: impl Iterator<Item = (&'b str, &'b str)>) -> crc32fast::Hasher {
    let mut meta: Vec<_> = meta.filter(|(key, _)| *key != CHECKSUM_KEY).collect();
    meta.sort();
    let mut crc = crc32fast::Hasher::new();
    for (key, value) in meta {
        field_start(&mut crc, key.as_bytes());
        field_start(&mut crc, value.as_bytes());
    }
    crc
}

/// One field of the checksum: its length, then its bytes.
fn field_start(crc: &mut crc32fast::Hasher, bytes: &[u8]) {
    crc.update(&(bytes.len() as u64).to_le_bytes());
    crc.update(bytes);
}

fn io_error(path: &Path, what: &str, e: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source: std::io::Error::new(e.kind(), format!("{what}: {e}")),
    }
}

/// Largest JSON header read: a map's lists a few dozen tensors and its
/// settings (kilobytes), so a hostile file costs at most this to refuse.
const MAX_HEADER_BYTES: u64 = 16 << 20;

/// Metadata key of the archive's checksum (see [`checksum`]). Archives of
/// [`LEGACY_VERSION`] written before it was added have none and load
/// unchecked; every later one must have it.
const CHECKSUM_KEY: &str = "crc32";

/// Where a tensor lies in the archive's bytes.
struct Entry {
    dtype: Dtype,
    shape: Vec<usize>,
    /// Byte range within the whole file (header included).
    range: std::ops::Range<usize>,
}

/// The archive checksum: a CRC-32 over every metadata entry but the
/// checksum itself, then every tensor's name and bytes, each list in name
/// order (the order safetensors lays tensors out in is its own) and each
/// field preceded by its length, so that moving bytes from one field to
/// the next changes the sum. Written as 8 hexadecimal digits.
///
/// Public only for tests and fuzzers that edit an archive on purpose and
/// must seal it again to reach the checks behind the checksum.
#[doc(hidden)]
pub fn checksum<'b>(
    meta: impl Iterator<Item = (&'b str, &'b str)>,
    tensors: impl Iterator<Item = (&'b str, &'b [u8])>,
) -> String {
    let mut crc = meta_hasher(meta);
    let mut field = |bytes: &[u8]| field_start(&mut crc, bytes);
    let mut tensors: Vec<_> = tensors.collect();
    tensors.sort_by_key(|(name, _)| *name);
    for (name, data) in tensors {
        field(name.as_bytes());
        field(data);
    }
    format!("{:08x}", crc.finalize())
}

/// Whether `id` has the form [`new_run_id`](crate::mapper::new_run_id)
/// gives (and earlier versions gave): 8 to 64 hexadecimal digits.
fn is_run_id(id: &str) -> bool {
    (8..=64).contains(&id.len()) && id.bytes().all(|b| b.is_ascii_hexdigit())
}

/// The archive of `header` (its JSON, as a test or a fuzzer edited it) and
/// `data`, with its checksum sealed again over the edits wherever the
/// header still names each tensor's bytes and has a checksum at all, so
/// that the edits reach the checks behind the checksum.
#[doc(hidden)]
pub fn join_resealed(header: &serde_json::Map<String, serde_json::Value>, data: &[u8]) -> Vec<u8> {
    use serde_json::Value;
    let mut header = header.clone();
    let meta: Option<Vec<(&str, &str)>> = match header.get("__metadata__") {
        Some(Value::Object(m)) => m
            .iter()
            .map(|(k, v)| Some((k.as_str(), v.as_str()?)))
            .collect(),
        _ => None,
    };
    let tensors: Option<Vec<(&str, &[u8])>> = header
        .iter()
        .filter(|(k, _)| *k != "__metadata__")
        .map(|(name, t)| {
            let o = t["data_offsets"].as_array()?;
            let (s, e) = (o.first()?.as_u64()?, o.get(1)?.as_u64()?);
            Some((name.as_str(), data.get(s as usize..e as usize)?))
        })
        .collect();
    let sum = meta
        .zip(tensors)
        .map(|(m, t)| checksum(m.into_iter(), t.into_iter()));
    if let (Some(sum), Some(Value::Object(meta))) = (sum, header.get_mut("__metadata__")) {
        if meta.contains_key(CHECKSUM_KEY) {
            meta.insert(CHECKSUM_KEY.into(), Value::String(sum));
        }
    }
    let text = serde_json::to_vec(&header).expect("a JSON map serialises");
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend(text);
    out.extend_from_slice(data);
    out
}

/// The metadata and tensors a header lists.
type Header = (HashMap<String, String>, HashMap<String, Entry>);

/// Reads only the header of the archive at `path` and checks that its
/// tensors tile the rest of the file exactly. Returns the header and the
/// open file.
fn check_extent(path: &Path, what: &str) -> Result<(Header, std::fs::File)> {
    use std::io::Read;
    let mut file = latentam_io::open_input(path).map_err(|e| io_error(path, "opening", e))?;
    let len = file
        .metadata()
        .map_err(|e| io_error(path, "reading", e))?
        .len();
    let mut size = [0u8; 8];
    let mut head = Vec::new();
    if file.read_exact(&mut size).is_ok() {
        let n = u64::from_le_bytes(size).min(MAX_HEADER_BYTES + 1);
        head.extend_from_slice(&size);
        (&mut file)
            .take(n)
            .read_to_end(&mut head)
            .map_err(|e| io_error(path, "reading", e))?;
    }
    let header = read_header_of(&head, len)
        .map_err(|why| Error::damaged(path, format!("not a latentam {what}: {why}")))?;
    Ok((header, file))
}

/// Reads a safetensors header and checks every tensor's extent: element
/// count times size (no overflow), offsets contiguous from the start of
/// the data, which they cover exactly. Returns the metadata and the
/// tensors. (Done here rather than by `safetensors::SafeTensors`, whose
/// 0.8 reader overflows on offsets near `usize::MAX`.)
#[allow(clippy::type_complexity)]
fn read_header(
    bytes: &[u8],
) -> std::result::Result<(HashMap<String, String>, HashMap<String, Entry>), String> {
    read_header_of(bytes, bytes.len() as u64)
}

/// [`read_header`] of a file of `file_len` bytes whose first bytes (the
/// header at least) are `bytes`.
#[allow(clippy::type_complexity)]
fn read_header_of(
    bytes: &[u8],
    file_len: u64,
) -> std::result::Result<(HashMap<String, String>, HashMap<String, Entry>), String> {
    let Some(n) = bytes.get(..8) else {
        return Err(format!("{file_len} bytes, shorter than a header"));
    };
    let mut len = [0u8; 8];
    len.copy_from_slice(n);
    let n = u64::from_le_bytes(len);
    if n > MAX_HEADER_BYTES {
        return Err(format!("header of {n} bytes"));
    }
    let data_start = 8 + n as usize;
    let Some(header) = bytes.get(8..data_start) else {
        return Err(format!("header of {n} bytes in a file of {file_len} bytes"));
    };
    let Ok(file_len) = usize::try_from(file_len) else {
        return Err(format!("{file_len} bytes do not fit this machine's memory"));
    };
    let header = std::str::from_utf8(header).map_err(|e| format!("header: {e}"))?;
    latentam_io::check_json_keys(header).map_err(|e| format!("header: {e}"))?;
    let fields: HashMap<String, serde_json::Value> =
        serde_json::from_str(header).map_err(|e| format!("header: {e}"))?;
    let mut meta = HashMap::new();
    let mut tensors = HashMap::with_capacity(fields.len());
    let data_len = file_len - data_start;
    for (name, value) in fields {
        if name == "__metadata__" {
            meta = serde_json::from_value(value).map_err(|e| format!("metadata: {e}"))?;
            continue;
        }
        let info: safetensors::tensor::TensorInfo =
            serde_json::from_value(value).map_err(|e| format!("tensor `{name}`: {e}"))?;
        let (s, e) = info.data_offsets;
        let bits = info
            .shape
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .and_then(|count| count.checked_mul(info.dtype.bitsize()));
        let size = match bits {
            Some(b) if b % 8 == 0 => b / 8,
            _ => {
                return Err(format!(
                    "tensor `{name}`: shape {:?} of {:?} has no whole byte size",
                    info.shape, info.dtype
                ))
            }
        };
        if e < s || e - s != size || e > data_len {
            return Err(format!(
                "tensor `{name}`: offsets {s}..{e} for {size} bytes in {data_len} bytes of data"
            ));
        }
        tensors.insert(
            name,
            Entry {
                dtype: info.dtype,
                shape: info.shape,
                range: data_start + s..data_start + e,
            },
        );
    }
    // The tensors tile the data exactly.
    let mut extents: Vec<_> = tensors.values().map(|t| t.range.clone()).collect();
    extents.sort_by_key(|r| (r.start, r.end));
    let mut at = data_start;
    for r in extents {
        if r.start != at {
            return Err(format!(
                "tensor data overlaps or leaves a gap at byte {}",
                at.min(r.start)
            ));
        }
        at = r.end;
    }
    if at != file_len {
        return Err(format!(
            "{} bytes after the last tensor",
            file_len.saturating_sub(at)
        ));
    }
    Ok((meta, tensors))
}

/// Where an archive's tensors are read from.
enum Source<'a> {
    /// The whole file in memory, owned (read from a path) or borrowed
    /// (parsed from memory).
    Bytes(Cow<'a, [u8]>),
    /// The file itself, read a tensor (or a part of one) at a time: an
    /// archive larger than memory.
    File(std::sync::Mutex<std::fs::File>),
}

/// A loaded archive, checked: format, version, extents and checksum.
pub(crate) struct Archive<'a> {
    source: Source<'a>,
    meta: HashMap<String, String>,
    tensors: HashMap<String, Entry>,
    path: PathBuf,
}

impl Archive<'static> {
    /// Reads and checks `path`: a safetensors file of this format and a
    /// version this build reads.
    pub fn open(path: &Path) -> Result<Self> {
        Self::open_as(path, FORMAT, VERSION, "map")
    }

    /// Reads and checks `path` as an archive of format `format`, version
    /// `version`; `what` names it in errors.
    pub fn open_as(path: &Path, format: &str, version: u32, what: &str) -> Result<Self> {
        // The header first: a file whose tensors do not tile it exactly (a
        // huge sparse file behind a small header, say) is refused before
        // its bulk is read.
        check_extent(path, what)?;
        let bytes = latentam_io::read_input(path).map_err(|e| io_error(path, "reading", e))?;
        Archive::parse_as(Cow::Owned(bytes), path, format, version, what)
    }

    /// [`Archive::open`] without holding the file in memory: the header
    /// is read and checked, the checksum verified by reading the file once
    /// in pieces, and tensors are read from the file when asked for (see
    /// [`Archive::for_each_rows`]). For maps larger than memory.
    pub fn open_streaming(path: &Path) -> Result<Self> {
        let ((meta, tensors), file) = check_extent(path, "map")?;
        let file = std::sync::Mutex::new(file);
        let mut buf = Vec::new();
        check_archive(&meta, &tensors, path, FORMAT, VERSION, "map", |t, crc| {
            let mut file = file.lock().unwrap_or_else(|e| e.into_inner());
            for piece in pieces(t.range.clone()) {
                read_range(&mut file, piece, &mut buf).map_err(|e| io_error(path, "reading", e))?;
                crc.update(&buf);
            }
            Ok(())
        })?;
        Ok(Archive {
            source: Source::File(file),
            meta,
            tensors,
            path: path.to_path_buf(),
        })
    }
}

/// Bytes read from a file at a time.
const PIECE: usize = 1 << 20;

/// `range` cut into pieces of at most [`PIECE`] bytes.
fn pieces(range: std::ops::Range<usize>) -> impl Iterator<Item = std::ops::Range<usize>> {
    range
        .clone()
        .step_by(PIECE)
        .map(move |at| at..(at + PIECE).min(range.end))
}

/// Reads `range` of `file` into `buf` (resized to it).
fn read_range(
    file: &mut std::fs::File,
    range: std::ops::Range<usize>,
    buf: &mut Vec<u8>,
) -> std::io::Result<()> {
    use std::io::{Read, Seek};
    buf.resize(range.len(), 0);
    file.seek(std::io::SeekFrom::Start(range.start as u64))?;
    file.read_exact(buf)
}

/// Checks an archive's header against the format, version and checksum it
/// must have; `feed` hashes one tensor's bytes.
fn check_archive(
    meta: &HashMap<String, String>,
    tensors: &HashMap<String, Entry>,
    origin: &Path,
    format: &str,
    version: u32,
    what: &str,
    mut feed: impl FnMut(&Entry, &mut crc32fast::Hasher) -> Result<()>,
) -> Result<()> {
    let not_ours = |why: String| Error::damaged(origin, format!("not a latentam {what}: {why}"));
    match meta.get("format").map(String::as_str) {
        Some(f) if f == format => {}
        other => return Err(not_ours(format!("format is {other:?}"))),
    }
    let found = meta.get("version").map(String::as_str).unwrap_or("none");
    let legacy = found == LEGACY_VERSION.to_string();
    if found != version.to_string() && !legacy {
        let found: String = found.chars().take(32).collect();
        return Err(Error::damaged(
            origin,
            format!(
                "a version {found} {what}; this build reads versions {LEGACY_VERSION} and \
                 {version}"
            ),
        ));
    }
    if !legacy && !meta.contains_key(CHECKSUM_KEY) {
        return Err(Error::damaged(
            origin,
            format!(
                "this {what} is damaged: a version {version} {what} without its checksum \
                 (the `{CHECKSUM_KEY}` entry was removed); use another copy or the run's \
                 last save"
            ),
        ));
    }
    if let Some(want) = meta.get(CHECKSUM_KEY) {
        // As [`checksum`] computes it, the tensors fed piece by piece.
        let mut hasher = meta_hasher(meta.iter().map(|(k, v)| (k.as_str(), v.as_str())));
        let mut names: Vec<&String> = tensors.keys().collect();
        names.sort();
        for name in names {
            let t = &tensors[name];
            field_start(&mut hasher, name.as_bytes());
            hasher.update(&(t.range.len() as u64).to_le_bytes());
            feed(t, &mut hasher)?;
        }
        let got = format!("{:08x}", hasher.finalize());
        if *want != got {
            let want: String = want.chars().take(16).collect();
            return Err(Error::damaged(
                origin,
                format!(
                    "this {what} is damaged: its checksum is {want:?}, its contents give \
                     {got} (a byte changed on disk or in a copy); use another copy or the \
                     run's last save"
                ),
            ));
        }
    }
    Ok(())
}

impl<'a> Archive<'a> {
    /// Checks `bytes` (the contents of `origin`, which names it in errors)
    /// as an archive of format `format`, version `version`. Every
    /// tensor's extent is checked here, so later reads cannot fail on it.
    pub fn parse_as(
        bytes: Cow<'a, [u8]>,
        origin: &Path,
        format: &str,
        version: u32,
        what: &str,
    ) -> Result<Self> {
        let (meta, tensors) = read_header(&bytes)
            .map_err(|why| Error::damaged(origin, format!("not a latentam {what}: {why}")))?;
        check_archive(&meta, &tensors, origin, format, version, what, |t, crc| {
            crc.update(&bytes[t.range.clone()]);
            Ok(())
        })?;
        Ok(Archive {
            source: Source::Bytes(bytes),
            meta,
            tensors,
            path: origin.to_path_buf(),
        })
    }

    /// Whether the archive carries a checksum, which every archive of this
    /// version does (and which was checked when it was parsed).
    pub fn sealed(&self) -> bool {
        self.meta.contains_key(CHECKSUM_KEY)
    }

    /// The run id in the metadata (see
    /// [`new_run_id`](crate::mapper::new_run_id)): 8 to 64 hexadecimal
    /// digits when present. Whether a file must carry one is its reader's
    /// rule (a saved state must, a decoder written on its own need not).
    pub fn run_id(&self) -> Result<Option<String>> {
        match self.meta.get("run_id") {
            Some(id) if is_run_id(id) => Ok(Some(id.clone())),
            Some(id) => Err(self.corrupt(format!(
                "run id \"{}\" is not one this tool writes (8 to 64 hexadecimal digits)",
                latentam_base::text::shown(id)
            ))),
            None => Ok(None),
        }
    }

    /// The file the archive came from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// [`Error::Damaged`] naming the file.
    pub fn corrupt(&self, why: String) -> Error {
        Error::damaged(&self.path, why)
    }

    /// A metadata value.
    pub fn meta(&self, key: &str) -> Result<&str> {
        self.meta
            .get(key)
            .map(String::as_str)
            .ok_or_else(|| self.corrupt(format!("metadata `{key}` missing")))
    }

    /// A metadata value parsed.
    pub fn meta_parse<T: std::str::FromStr>(&self, key: &str) -> Result<T> {
        let v = self.meta(key)?;
        v.parse().map_err(|_| {
            let shown: String = v.chars().take(64).collect();
            self.corrupt(format!("metadata `{key}` = {shown:?} is malformed"))
        })
    }

    /// Whether tensor `name` is present.
    pub fn has(&self, name: &str) -> bool {
        self.tensors.contains_key(name)
    }

    fn entry<T: Element>(&self, name: &str) -> Result<&Entry> {
        let t = self
            .tensors
            .get(name)
            .ok_or_else(|| self.corrupt(format!("tensor `{name}` missing")))?;
        if t.dtype != T::DTYPE {
            return Err(self.corrupt(format!(
                "tensor `{name}` is {:?}, expected {:?}",
                t.dtype,
                T::DTYPE
            )));
        }
        Ok(t)
    }

    /// The shape of tensor `name`, which must be of type `T`.
    pub fn shape<T: Element>(&self, name: &str) -> Result<&[usize]> {
        Ok(&self.entry::<T>(name)?.shape)
    }

    fn data<T: Element>(&self, name: &str, t: &Entry) -> Result<Vec<T>> {
        self.data_range(name, t.range.clone())
    }

    /// `range` of the file as values of `T`.
    fn data_range<T: Element>(&self, name: &str, range: std::ops::Range<usize>) -> Result<Vec<T>> {
        let out_of_range = || self.corrupt(format!("tensor `{name}` data out of range"));
        if !range.len().is_multiple_of(std::mem::size_of::<T>()) {
            return Err(out_of_range());
        }
        match &self.source {
            Source::Bytes(bytes) => {
                let raw = bytes.get(range).ok_or_else(out_of_range)?;
                Ok(bytemuck::allocation::pod_collect_to_vec(raw))
            }
            Source::File(file) => {
                let mut file = file.lock().unwrap_or_else(|e| e.into_inner());
                let mut buf = Vec::new();
                read_range(&mut file, range, &mut buf)
                    .map_err(|e| io_error(&self.path, "reading", e))?;
                Ok(bytemuck::allocation::pod_collect_to_vec(&buf))
            }
        }
    }

    /// Checks that tensor `name` is of `T` and exactly `shape`.
    pub fn exact_shape<T: Element>(&self, name: &str, shape: &[usize]) -> Result<()> {
        let t = self.entry::<T>(name)?;
        if t.shape != shape {
            return Err(self.corrupt(format!(
                "tensor `{name}` has shape {:?}, expected {shape:?}",
                t.shape
            )));
        }
        Ok(())
    }

    /// Rows `first..first + count` of tensor `name` (rows along its first
    /// dimension): a part of a tensor too large to read whole.
    pub fn rows<T: Element>(&self, name: &str, first: usize, count: usize) -> Result<Vec<T>> {
        let t = self.entry::<T>(name)?;
        let rows = t.shape.first().copied().unwrap_or(1);
        let end = first.checked_add(count).filter(|&e| e <= rows);
        let Some(end) = end else {
            return Err(self.corrupt(format!(
                "rows {first}..{first}+{count} of tensor `{name}`, which has {rows}"
            )));
        };
        let row_bytes = t.range.len().checked_div(rows).unwrap_or(0);
        let start = t.range.start + first * row_bytes;
        self.data_range(name, start..t.range.start + end * row_bytes)
    }

    /// Tensor `name` of exactly `shape`.
    pub fn exact<T: Element>(&self, name: &str, shape: &[usize]) -> Result<Vec<T>> {
        let t = self.entry::<T>(name)?;
        if t.shape != shape {
            return Err(self.corrupt(format!(
                "tensor `{name}` has shape {:?}, expected {shape:?}",
                t.shape
            )));
        }
        self.data(name, t)
    }

    /// Tensor `name`, one-dimensional, of any length.
    pub fn flat<T: Element>(&self, name: &str) -> Result<Vec<T>> {
        let t = self.entry::<T>(name)?;
        if t.shape.len() != 1 {
            return Err(self.corrupt(format!(
                "tensor `{name}` has shape {:?}, expected one dimension",
                t.shape
            )));
        }
        self.data(name, t)
    }
}

#[cfg(test)]
#[path = "archive_tests.rs"]
mod tests;
