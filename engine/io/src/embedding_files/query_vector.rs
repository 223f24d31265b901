//! One embedding vector to query a map with (`latentam query
//! --embedding`): a text embedding from a vision-language model's text
//! encoder.

use std::path::Path;

use latentam_base::{Error, Result};

use super::tensor::{bad, floats, npy_tensor, open_safetensors, safetensors_tensor};

/// Reads one embedding vector (e.g. a text embedding to query with) from
/// a `.npy` file (F16/F32, shape `[D]` or `[1, D]`) or a `.safetensors`
/// file holding one such tensor (or several, one named `embedding`).
/// A file that cannot be read is [`Error::Io`]; one that is no `.npy` or
/// safetensors file is [`Error::Damaged`], one that holds no such vector
/// [`Error::BadInput`], both naming the file.
pub fn read_vector(path: &Path) -> Result<Vec<f32>> {
    let bytes = crate::read_input(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    vector_from_bytes(
        &bytes,
        path.extension().is_some_and(|e| e == "safetensors"),
        &path.display().to_string(),
    )
}

/// [`read_vector`] of a file's bytes: `.safetensors` when `safetensors`,
/// `.npy` otherwise; `origin` names the file in errors.
pub fn vector_from_bytes(bytes: &[u8], safetensors: bool, origin: &str) -> Result<Vec<f32>> {
    let tensor = if safetensors {
        let st = open_safetensors(bytes, origin)?;
        let names = st.names();
        let name = match names.as_slice() {
            [one] => one.to_string(),
            _ if names.contains(&"embedding") => "embedding".to_string(),
            _ => {
                return Err(bad(
                    origin,
                    format!(
                        "{} tensors ({}); keep one, or name the query `embedding`",
                        names.len(),
                        names
                            .iter()
                            .map(|n| latentam_base::text::shown(n))
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                ))
            }
        };
        // `name` is one of `st.names()`, so the tensor exists.
        safetensors_tensor(&st, &name, origin)?.expect("listed above")
    } else {
        npy_tensor(bytes, origin).map_err(|e| match e {
            Error::Damaged { path, reason } => Error::Damaged {
                path,
                reason: format!("not a .npy array: {reason}"),
            },
            e => e,
        })?
    };
    let len = tensor
        .shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or_else(|| bad(origin, format!("shape {:?} overflows", tensor.shape)))?;
    if tensor.shape.iter().filter(|&&d| d != 1).count() > 1 || len == 0 {
        return Err(bad(
            origin,
            format!(
                "shape {:?}; one vector ([D] or [1, D]) is expected",
                tensor.shape
            ),
        ));
    }
    let v = floats(&tensor, origin)?;
    if v.iter().all(|&x| x == 0.0) {
        return Err(bad(origin, "the vector is all zeros"));
    }
    Ok(v)
}
