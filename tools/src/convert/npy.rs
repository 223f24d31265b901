//! Reading (and, for tests, writing) NumPy `.npy` arrays: the formats a
//! user's feature extractor most likely writes.

use anyhow::{bail, Context};

/// Element types the converters accept.
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

fn field<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let at = header.find(&format!("'{key}'"))? + key.len() + 2;
    let rest = header[at..].trim_start().strip_prefix(':')?.trim_start();
    Some(rest)
}

/// Parses `.npy` bytes (format versions 1–3, little-endian, C order).
pub fn parse(bytes: &[u8]) -> anyhow::Result<Npy> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        bail!("not a .npy file (no \\x93NUMPY magic)");
    }
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => bail!(".npy format version {v} is not supported"),
    };
    let header = bytes
        .get(start..start + header_len)
        .context(".npy header runs past the end of the file")?;
    let header = std::str::from_utf8(header).context(".npy header is not text")?;
    // The header is a Python dict literal, where a key named twice means
    // its last value; `field` reads the first, so neither may be trusted.
    for key in ["descr", "fortran_order", "shape"] {
        if header.matches(&format!("'{key}'")).count() > 1 {
            bail!(".npy header names `{key}` twice");
        }
    }
    let descr = field(header, "descr").context(".npy header has no descr")?;
    let descr = descr
        .trim_start_matches('\'')
        .split('\'')
        .next()
        .unwrap_or("");
    let dtype = NpyType::parse(descr).with_context(|| {
        format!("element type `{descr}` (accepted: |u1 <u2 <i4 <i8 <f2 <f4, little-endian)")
    })?;
    let fortran = field(header, "fortran_order").context(".npy header has no fortran_order")?;
    if fortran.starts_with("True") {
        bail!("Fortran-ordered .npy arrays are not supported; save with np.ascontiguousarray");
    }
    let shape = field(header, "shape").context(".npy header has no shape")?;
    let shape = shape
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .context(".npy shape is not a tuple")?;
    let shape: Vec<usize> = shape
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse()
                .with_context(|| format!("bad .npy dimension `{s}`"))
        })
        .collect::<anyhow::Result<_>>()?;
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .context(".npy shape overflows")?;
    let data = &bytes[start + header_len..];
    let need = count
        .checked_mul(dtype.size())
        .context(".npy shape overflows")?;
    if data.len() != need {
        bail!(
            ".npy data has {} bytes, shape {shape:?} of {descr} needs {need}",
            data.len()
        );
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
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_errors() {
        let data: Vec<u8> = (0..24u8).collect();
        let bytes = write(NpyType::F16, &[3, 4], &data);
        assert_eq!(
            (10 + u16::from_le_bytes([bytes[8], bytes[9]]) as usize) % 64,
            0
        );
        let a = parse(&bytes).unwrap();
        assert_eq!(
            (a.dtype, a.shape.as_slice(), a.data.as_slice()),
            (NpyType::F16, &[3, 4][..], &data[..])
        );
        let v = parse(&write(NpyType::U16, &[5], &[0; 10])).unwrap();
        assert_eq!(v.shape, [5]);
        assert!(parse(&bytes[..bytes.len() - 1]).is_err());
        assert!(parse(b"hello world").is_err());
        let mut big = write(NpyType::F32, &[2], &[0; 8]);
        let at = big.windows(3).position(|w| w == b"<f4").unwrap();
        big[at] = b'>';
        assert!(parse(&big).unwrap_err().to_string().contains(">f4"));
    }

    #[test]
    fn a_header_naming_a_key_twice_is_refused() {
        // The same length as the written header, so the data still fits.
        let good = write(NpyType::F32, &[2], &[0; 8]);
        for (from, to) in [
            ("'fortran_order': False", "'shape': (4,)"),
            ("'fortran_order': False", "'descr': '<f2'"),
        ] {
            let at = good
                .windows(from.len())
                .position(|w| w == from.as_bytes())
                .unwrap();
            let to = format!("{to:<width$}", width = from.len());
            let mut bad = good.clone();
            bad[at..at + from.len()].copy_from_slice(to.as_bytes());
            let e = parse(&bad).unwrap_err().to_string();
            assert!(e.contains("twice"), "{e}");
        }
    }
}
