//! What the embedding readers share: a tensor from either file format,
//! checked safetensors files, and element conversion with the checks every
//! reader makes (finite values, labels in range, dimensions a log can
//! hold).

use std::collections::HashMap;

use latentam_base::{Error, Result};

use super::npy::{self, Npy, NpyType};
use crate::MAX_EMBEDDING_DIM;

/// A tensor from either file format.
pub(super) struct Tensor {
    pub(super) dtype: NpyType,
    pub(super) shape: Vec<usize>,
    pub(super) data: Vec<u8>,
}

impl From<Npy> for Tensor {
    fn from(n: Npy) -> Self {
        Tensor {
            dtype: n.dtype,
            shape: n.shape,
            data: n.data,
        }
    }
}

/// A file whose contents the readers refuse ([`Error::BadInput`] naming
/// the file, `origin`, and saying why): the caller fixes the file.
pub(super) fn bad(origin: &str, why: impl Into<String>) -> Error {
    Error::bad_input(origin, why)
}

/// A file that is not what it claims to be (no `.npy` or safetensors
/// file, cut short, another version): [`Error::Damaged`] naming it.
pub(super) fn damaged(origin: &str, why: impl Into<String>) -> Error {
    Error::damaged(origin, why)
}

/// An error of [`npy::parse`], which knows no file, as the damage of the
/// file `origin`.
fn within(origin: &str, e: Error) -> Error {
    match e {
        Error::BadInput { reason, .. } => damaged(origin, reason),
        other => other,
    }
}

/// The `.npy` array in `bytes`; errors begin with `origin`.
pub(super) fn npy_tensor(bytes: &[u8], origin: &str) -> Result<Tensor> {
    npy::parse(bytes)
        .map(Tensor::from)
        .map_err(|e| within(origin, e))
}

/// `bytes` as a safetensors file whose header names each key once.
pub(super) fn open_safetensors<'a>(
    bytes: &'a [u8],
    origin: &str,
) -> Result<safetensors::SafeTensors<'a>> {
    crate::check_safetensors_keys(bytes).map_err(|e| damaged(origin, e))?;
    safetensors::SafeTensors::deserialize(bytes)
        .map_err(|e| damaged(origin, format!("not a safetensors file: {e}")))
}

/// The metadata of the safetensors file `bytes` (empty when it has none).
pub(super) fn safetensors_metadata(bytes: &[u8], origin: &str) -> Result<HashMap<String, String>> {
    let (_, meta) = safetensors::SafeTensors::read_metadata(bytes)
        .map_err(|e| damaged(origin, format!("not a safetensors file: {e}")))?;
    Ok(meta.metadata().clone().unwrap_or_default())
}

/// The tensor `name` of `st`, `None` when it has none.
pub(super) fn safetensors_tensor(
    st: &safetensors::SafeTensors<'_>,
    name: &str,
    origin: &str,
) -> Result<Option<Tensor>> {
    let Ok(view) = st.tensor(name) else {
        return Ok(None);
    };
    use safetensors::Dtype as D;
    let dtype = match view.dtype() {
        D::U8 => NpyType::U8,
        D::U16 => NpyType::U16,
        D::I32 => NpyType::I32,
        D::I64 => NpyType::I64,
        D::F16 => NpyType::F16,
        D::F32 => NpyType::F32,
        other => {
            return Err(bad(
                origin,
                format!("tensor `{name}` has type {other:?} (accepted: U8 U16 I32 I64 F16 F32)"),
            ))
        }
    };
    Ok(Some(Tensor {
        dtype,
        shape: view.shape().to_vec(),
        data: view.data().to_vec(),
    }))
}

/// The values of a F16 or F32 tensor, all finite.
pub(super) fn floats(t: &Tensor, what: &str) -> Result<Vec<f32>> {
    let v: Vec<f32> = match t.dtype {
        NpyType::F32 => t
            .data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
        NpyType::F16 => t
            .data
            .chunks_exact(2)
            .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
            .collect(),
        other => return Err(bad(what, format!("must be F16 or F32, not {other:?}"))),
    };
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(bad(what, format!("a non-finite value at element {i}")));
    }
    Ok(v)
}

/// The labels of an integer tensor, -1 (signed types) read as 65535.
pub(super) fn labels(t: &Tensor, what: &str) -> Result<Vec<u16>> {
    let convert = |v: i64| -> Result<u16> {
        match v {
            -1 => Ok(u16::MAX),
            0..=65535 => Ok(v as u16),
            _ => Err(bad(what, format!("label {v} outside -1…65535"))),
        }
    };
    match t.dtype {
        NpyType::U8 => Ok(t.data.iter().map(|&b| b as u16).collect()),
        NpyType::U16 => Ok(t
            .data
            .chunks_exact(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .collect()),
        NpyType::I32 => t
            .data
            .chunks_exact(4)
            .map(|b| convert(i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as i64))
            .collect(),
        NpyType::I64 => t
            .data
            .chunks_exact(8)
            // `chunks_exact(8)` gives 8-byte slices.
            .map(|b| convert(i64::from_le_bytes(b.try_into().expect("8 bytes"))))
            .collect(),
        other => Err(bad(what, format!("must be an integer type, not {other:?}"))),
    }
}

/// `v` as a `u32`, or an error naming what it is: sizes from a file are
/// written to messages as `u32`s.
pub(super) fn size_u32(v: usize, what: &str) -> Result<u32> {
    u32::try_from(v).map_err(|_| bad(what, format!("{v} is too large")))
}

/// An embedding dimension from a file, checked against what a log may hold.
pub(super) fn dim_of(d: usize, origin: &str) -> Result<u32> {
    match u32::try_from(d) {
        Ok(d) if (1..=MAX_EMBEDDING_DIM).contains(&d) => Ok(d),
        _ => Err(bad(
            origin,
            format!("embedding dimension {d} is out of range (1…{MAX_EMBEDDING_DIM})"),
        )),
    }
}
