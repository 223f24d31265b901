//! Reading (and, for tests, writing) NumPy `.npy` arrays: the formats a
//! user's feature extractor most likely writes.

use latentam_base::{Error, Result};

/// Element types the readers accept.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NpyType {
    /// `<u1` / `|u1`.
    U8,
    /// `<u2`.
    U16,
    /// `<i4`.
    I32,
    /// `<i8`.
    I64,
    /// `<f2`.
    F16,
    /// `<f4`.
    F32,
}

impl NpyType {
    fn parse(descr: &str) -> Option<Self> {
        Some(match descr {
            "<u1" | "|u1" => NpyType::U8,
            "<u2" => NpyType::U16,
            "<i4" => NpyType::I32,
            "<i8" => NpyType::I64,
            "<f2" => NpyType::F16,
            "<f4" => NpyType::F32,
            _ => return None,
        })
    }
    fn descr(self) -> &'static str {
        match self {
            NpyType::U8 => "|u1",
            NpyType::U16 => "<u2",
            NpyType::I32 => "<i4",
            NpyType::I64 => "<i8",
            NpyType::F16 => "<f2",
            NpyType::F32 => "<f4",
        }
    }
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            NpyType::U8 => 1,
            NpyType::U16 | NpyType::F16 => 2,
            NpyType::I32 | NpyType::F32 => 4,
            NpyType::I64 => 8,
        }
    }
}

/// A parsed array: element type, shape, little-endian C-order data.
#[derive(Clone, Debug, PartialEq)]
pub struct Npy {
    /// Element type.
    pub dtype: NpyType,
    /// Shape.
    pub shape: Vec<usize>,
    /// Raw data.
    pub data: Vec<u8>,
}

/// Bytes that are no `.npy` array this reader takes.
fn bad(why: impl Into<String>) -> Error {
    Error::bad_input(".npy data", why)
}

fn field<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let at = header.find(&format!("'{key}'"))? + key.len() + 2;
    let rest = header[at..].trim_start().strip_prefix(':')?.trim_start();
    Some(rest)
}

/// Parses `.npy` bytes (format versions 1–3, little-endian, C order). A
/// file it cannot read is [`Error::BadInput`] saying why (the readers of
/// [`embedding_files`](super) turn it into [`Error::Damaged`] naming the
/// file).
///
/// ```
/// use latentam_io::embedding_files::npy::{self, NpyType};
///
/// let bytes = npy::write(NpyType::F32, &[2], &[0; 8]);
/// assert_eq!(npy::parse(&bytes)?.shape, [2]);
/// assert!(npy::parse(b"not an array").is_err());
/// # Ok::<(), latentam_io::Error>(())
/// ```
pub fn parse(bytes: &[u8]) -> Result<Npy> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(bad("not a .npy file (no \\x93NUMPY magic)"));
    }
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => return Err(bad(format!(".npy format version {v} is not supported"))),
    };
    let header = bytes
        .get(start..start + header_len)
        .ok_or_else(|| bad(".npy header runs past the end of the file"))?;
    let header =
        std::str::from_utf8(header).map_err(|e| bad(format!(".npy header is not text: {e}")))?;
    // The header is a Python dict literal, where a key named twice means
    // its last value; `field` reads the first, so neither may be trusted.
    for key in ["descr", "fortran_order", "shape"] {
        if header.matches(&format!("'{key}'")).count() > 1 {
            return Err(bad(format!(".npy header names `{key}` twice")));
        }
    }
    let descr = field(header, "descr").ok_or_else(|| bad(".npy header has no descr"))?;
    let descr = descr
        .trim_start_matches('\'')
        .split('\'')
        .next()
        .unwrap_or("");
    let dtype = NpyType::parse(descr).ok_or_else(|| {
        bad(format!(
            "element type `{descr}` (accepted: |u1 <u2 <i4 <i8 <f2 <f4, little-endian)"
        ))
    })?;
    let fortran =
        field(header, "fortran_order").ok_or_else(|| bad(".npy header has no fortran_order"))?;
    if fortran.starts_with("True") {
        return Err(bad(
            "Fortran-ordered .npy arrays are not supported; save with np.ascontiguousarray",
        ));
    }
    let shape = field(header, "shape").ok_or_else(|| bad(".npy header has no shape"))?;
    let shape = shape
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| bad(".npy shape is not a tuple"))?;
    let shape: Vec<usize> = shape
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse()
                .map_err(|e| bad(format!("bad .npy dimension `{s}`: {e}")))
        })
        .collect::<Result<_>>()?;
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or_else(|| bad(".npy shape overflows"))?;
    let data = &bytes[start + header_len..];
    let need = count
        .checked_mul(dtype.size())
        .ok_or_else(|| bad(".npy shape overflows"))?;
    if data.len() != need {
        return Err(bad(format!(
            ".npy data has {} bytes, shape {shape:?} of {descr} needs {need}",
            data.len()
        )));
    }
    Ok(Npy {
        dtype,
        shape,
        data: data.to_vec(),
    })
}

/// Serializes an array as `.npy` version 1.
pub fn write(dtype: NpyType, shape: &[usize], data: &[u8]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let tuple = if shape.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!(
        "{{'descr': '{}', 'fortran_order': False, 'shape': {tuple}, }}",
        dtype.descr()
    );
    let total = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - total % 64) % 64));
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(data);
    out
}

#[cfg(test)]
#[path = "npy_tests.rs"]
mod tests;
