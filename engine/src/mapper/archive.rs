//! The file a saved map lives in: one safetensors file (named tensors plus
//! string metadata), tagged with a format name and version, written
//! atomically (temporary file, fsync, rename, fsync of the directory) so a
//! crash leaves either the old file or the new one.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use safetensors::tensor::TensorView;
use safetensors::{Dtype, SafeTensors};

use crate::error::{Error, Result};

/// Format name stored in every archive's metadata.
pub const FORMAT: &str = "latentam-map";
/// Version this build writes and reads.
pub const VERSION: u32 = 1;

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
    /// `shape` must equal `data.len()`).
    pub fn tensor<T: Element>(&mut self, name: &str, shape: &[usize], data: &[T]) {
        debug_assert_eq!(shape.iter().product::<usize>(), data.len());
        self.tensors.push((
            name.to_string(),
            T::DTYPE,
            shape.to_vec(),
            bytemuck::cast_slice(data).to_vec(),
        ));
    }

    /// Adds raw rows: `rows` × `row_bytes` bytes.
    pub fn bytes(&mut self, name: &str, rows: usize, row_bytes: usize, data: Vec<u8>) {
        debug_assert_eq!(rows * row_bytes, data.len());
        self.tensors
            .push((name.to_string(), Dtype::U8, vec![rows, row_bytes], data));
    }

    /// Writes the archive to `path` atomically.
    pub fn write(mut self, path: &Path) -> Result<()> {
        let (format, version) = self.format.unwrap_or((FORMAT, VERSION));
        self.meta.insert("format".into(), format.into());
        self.meta.insert("version".into(), version.to_string());
        let views = self
            .tensors
            .iter()
            .map(|(name, dtype, shape, data)| {
                TensorView::new(*dtype, shape.clone(), data)
                    .map(|v| (name.clone(), v))
                    .map_err(|e| Error::InvalidArgument(format!("tensor `{name}`: {e}")))
            })
            .collect::<Result<Vec<_>>>()?;
        let bytes = safetensors::serialize(views, Some(self.meta))
            .map_err(|e| Error::InvalidArgument(format!("serialising the map: {e}")))?;
        crate::io::write_bytes_atomically(path, &bytes)
    }
}

fn io_error(path: &Path, what: &str, e: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source: std::io::Error::new(e.kind(), format!("{what}: {e}")),
    }
}

/// A loaded archive.
pub(crate) struct Archive {
    bytes: Vec<u8>,
    meta: HashMap<String, String>,
    names: std::collections::HashSet<String>,
    path: PathBuf,
}

impl Archive {
    /// Reads and checks `path`: a safetensors file of this format and a
    /// version this build reads.
    pub fn open(path: &Path) -> Result<Self> {
        Self::open_as(path, FORMAT, VERSION, "map")
    }

    /// Reads and checks `path` as an archive of format `format`, version
    /// `version`; `what` names it in errors.
    pub fn open_as(path: &Path, format: &str, version: u32, what: &str) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| io_error(path, "reading", e))?;
        let not_ours = |why: String| {
            Error::InvalidArgument(format!(
                "{} is not a latentam {what}: {why}",
                path.display()
            ))
        };
        let (_, header) =
            SafeTensors::read_metadata(&bytes).map_err(|e| not_ours(e.to_string()))?;
        let meta = header.metadata().clone().unwrap_or_default();
        match meta.get("format").map(String::as_str) {
            Some(f) if f == format => {}
            other => return Err(not_ours(format!("format is {other:?}"))),
        }
        let found = meta.get("version").map(String::as_str).unwrap_or("none");
        if found != version.to_string() {
            return Err(Error::InvalidArgument(format!(
                "{} is a version {found} {what}; this build reads version {version}",
                path.display()
            )));
        }
        // Check every tensor's extent now, so later reads cannot fail on it.
        let names = SafeTensors::deserialize(&bytes)
            .map_err(|e| not_ours(e.to_string()))?
            .names()
            .into_iter()
            .map(str::to_string)
            .collect();
        Ok(Archive {
            bytes,
            meta,
            names,
            path: path.to_path_buf(),
        })
    }

    fn corrupt(&self, why: String) -> Error {
        Error::InvalidArgument(format!("{}: {why}", self.path.display()))
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
        v.parse()
            .map_err(|_| self.corrupt(format!("metadata `{key}` = {v:?} is malformed")))
    }

    /// Whether tensor `name` is present.
    pub fn has(&self, name: &str) -> bool {
        self.names.contains(name)
    }

    /// Tensor `name` as `T`s with its shape; the stored type must be `T`.
    pub fn tensor<T: Element>(&self, name: &str) -> Result<(Vec<usize>, Vec<T>)> {
        let st = SafeTensors::deserialize(&self.bytes).map_err(|e| self.corrupt(e.to_string()))?;
        let t = st
            .tensor(name)
            .map_err(|_| self.corrupt(format!("tensor `{name}` missing")))?;
        if t.dtype() != T::DTYPE {
            return Err(self.corrupt(format!(
                "tensor `{name}` is {:?}, expected {:?}",
                t.dtype(),
                T::DTYPE
            )));
        }
        let data: Vec<T> = bytemuck::allocation::pod_collect_to_vec(t.data());
        Ok((t.shape().to_vec(), data))
    }

    /// Tensor `name`, checking that it holds `rows` rows of `width`
    /// elements (`width` 0: any row shape).
    pub fn rows<T: Element>(&self, name: &str, rows: usize, width: usize) -> Result<Vec<T>> {
        let (shape, data) = self.tensor::<T>(name)?;
        let ok = shape.first() == Some(&rows) && (width == 0 || data.len() == rows * width);
        if !ok {
            return Err(self.corrupt(format!(
                "tensor `{name}` has shape {shape:?}, expected {rows} rows of {width}"
            )));
        }
        Ok(data)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_refusals() {
        let dir = std::env::temp_dir().join(format!("latentam-archive-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.map");
        let mut w = ArchiveWriter::default();
        w.meta("answer", 42);
        w.tensor("x", &[2, 3], &[1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0]);
        w.tensor("k", &[2], &[-7i32, 9]);
        w.bytes("raw", 1, 3, vec![1, 2, 3]);
        w.write(&path).unwrap();
        let a = Archive::open(&path).unwrap();
        assert_eq!(a.meta_parse::<u32>("answer").unwrap(), 42);
        assert_eq!(a.rows::<f32>("x", 2, 3).unwrap()[5], 6.0);
        assert!(a.rows::<f32>("x", 3, 2).is_err());
        assert!(a.tensor::<i64>("k").is_err());
        assert!(a.tensor::<f32>("missing").is_err());
        assert!(a.meta("missing").is_err());
        assert!(a.has("raw") && !a.has("nope"));
        // No temporary files left behind.
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);

        // Truncated, foreign, or from a future version: clear errors.
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 5]).unwrap();
        assert!(Archive::open(&path).is_err());
        std::fs::write(&path, b"not a map at all").unwrap();
        let e = Archive::open(&path).err().unwrap().to_string();
        assert!(e.contains("not a latentam map"), "{e}");
        let views = vec![(
            "x".to_string(),
            TensorView::new(Dtype::U8, vec![1], &[0u8]).unwrap(),
        )];
        let mut meta = HashMap::new();
        meta.insert("format".to_string(), FORMAT.to_string());
        meta.insert("version".to_string(), "99".to_string());
        std::fs::write(&path, safetensors::serialize(views, Some(meta)).unwrap()).unwrap();
        let e = Archive::open(&path).err().unwrap().to_string();
        assert!(e.contains("version 99"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
