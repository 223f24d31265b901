//! The file a saved map lives in: one safetensors file (named tensors plus
//! string metadata), tagged with a format name and version, written
//! atomically (temporary file, fsync, rename, fsync of the directory) so a
//! crash leaves either the old file or the new one.

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use safetensors::tensor::TensorView;
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

/// Collects tensors and metadata, then writes them in one go.
#[derive(Default)]
pub(crate) struct ArchiveWriter {
    tensors: Vec<(String, Dtype, Vec<usize>, Vec<u8>)>,
    meta: HashMap<String, String>,
    /// Format name and version; unset: the map's.
    format: Option<(&'static str, u32)>,
}

impl ArchiveWriter {
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

    /// Adds `data` as a tensor of `shape` (row-major; the product of
    /// `shape` must equal `data.len()`, or [`ArchiveWriter::into_bytes`]
    /// fails).
    pub fn tensor<T: Element>(&mut self, name: &str, shape: &[usize], data: &[T]) {
        self.tensors.push((
            name.to_string(),
            T::DTYPE,
            shape.to_vec(),
            bytemuck::cast_slice(data).to_vec(),
        ));
    }

    /// Adds raw rows: `rows` × `row_bytes` bytes (checked like
    /// [`ArchiveWriter::tensor`]).
    pub fn bytes(&mut self, name: &str, rows: usize, row_bytes: usize, data: Vec<u8>) {
        self.tensors
            .push((name.to_string(), Dtype::U8, vec![rows, row_bytes], data));
    }

    /// The archive's bytes (write them with
    /// [`latentam_base::files::write_bytes_atomically`]).
    pub fn into_bytes(mut self) -> Result<Vec<u8>> {
        let (format, version) = self.format.unwrap_or((FORMAT, VERSION));
        self.meta.insert("format".into(), format.into());
        self.meta.insert("version".into(), version.to_string());
        // Checked at load: metadata and tensors alike.
        let sum = checksum(
            self.meta.iter().map(|(k, v)| (k.as_str(), v.as_str())),
            self.tensors.iter().map(|(n, _, _, d)| (n.as_str(), &d[..])),
        );
        self.meta.insert(CHECKSUM_KEY.into(), sum);
        let views = self
            .tensors
            .iter()
            .map(|(name, dtype, shape, data)| {
                TensorView::new(*dtype, shape.clone(), data)
                    .map(|v| (name.clone(), v))
                    .map_err(|e| Error::bad_input(format!("tensor `{name}`"), e.to_string()))
            })
            .collect::<Result<Vec<_>>>()?;
        let bytes = safetensors::serialize(views, Some(self.meta))
            .map_err(|e| Error::bad_input("serialising the map", e.to_string()))?;
        with_sorted_header(bytes)
    }
}

/// `bytes`, a file safetensors just wrote, with its metadata in key order.
/// safetensors writes the metadata in the order of a `HashMap`, which
/// differs from one process to the next: the same state would give other
/// bytes on every save, and tests that mutate a saved file at random would
/// not be reproducible from their seed. The entries are the same, so the
/// compact JSON is no longer; it is padded with spaces to the original
/// length (safetensors pads its header the same way), so the tensors'
/// offsets hold.
fn with_sorted_header(mut bytes: Vec<u8>) -> Result<Vec<u8>> {
    use std::collections::BTreeMap;
    let ours = |why: String| Error::bad_input("serialising the map", why);
    let n = bytes
        .get(..8)
        .and_then(|b| b.try_into().ok())
        .map(u64::from_le_bytes)
        .and_then(|n| usize::try_from(n).ok())
        .filter(|n| n.checked_add(8).is_some_and(|end| end <= bytes.len()))
        .ok_or_else(|| ours("safetensors wrote no header".into()))?;
    let header = &bytes[8..8 + n];
    // Sorted explicitly (BTreeMap), not through serde_json's own map,
    // whose order depends on a feature another crate may turn on.
    let mut top: BTreeMap<String, serde_json::Value> =
        serde_json::from_slice(header).map_err(|e| ours(e.to_string()))?;
    if let Some(meta) = top.get_mut("__metadata__") {
        let sorted: BTreeMap<String, serde_json::Value> =
            serde_json::from_value(meta.take()).map_err(|e| ours(e.to_string()))?;
        *meta = serde_json::to_value(sorted).map_err(|e| ours(e.to_string()))?;
    }
    let mut text = serde_json::to_vec(&top).map_err(|e| ours(e.to_string()))?;
    if text.len() > n {
        return Err(ours("the sorted header came out longer".into()));
    }
    text.resize(n, b' ');
    bytes[8..8 + n].copy_from_slice(&text);
    Ok(bytes)
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
    let mut crc = crc32fast::Hasher::new();
    let mut field = |bytes: &[u8]| {
        crc.update(&(bytes.len() as u64).to_le_bytes());
        crc.update(bytes);
    };
    let mut meta: Vec<_> = meta.filter(|(key, _)| *key != CHECKSUM_KEY).collect();
    meta.sort();
    for (key, value) in meta {
        field(key.as_bytes());
        field(value.as_bytes());
    }
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

/// Reads only the header of the archive at `path` and checks that its
/// tensors tile the rest of the file exactly.
fn check_extent(path: &Path, what: &str) -> Result<()> {
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
    read_header_of(&head, len)
        .map(|_| ())
        .map_err(|why| Error::damaged(path, format!("not a latentam {what}: {why}")))
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

/// A loaded archive: the file's bytes, owned (read from a path) or
/// borrowed (parsed from memory).
pub(crate) struct Archive<'a> {
    bytes: Cow<'a, [u8]>,
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
        let not_ours =
            |why: String| Error::damaged(origin, format!("not a latentam {what}: {why}"));
        let (meta, tensors) = read_header(&bytes).map_err(not_ours)?;
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
            let got = checksum(
                meta.iter().map(|(k, v)| (k.as_str(), v.as_str())),
                tensors
                    .iter()
                    .map(|(n, t)| (n.as_str(), &bytes[t.range.clone()])),
            );
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
        Ok(Archive {
            bytes,
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
        let raw = self
            .bytes
            .get(t.range.clone())
            .filter(|b| b.len() % std::mem::size_of::<T>() == 0)
            .ok_or_else(|| self.corrupt(format!("tensor `{name}` data out of range")))?;
        Ok(bytemuck::allocation::pod_collect_to_vec(raw))
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
