//! One frame's embeddings from the files a user's own extractor writes
//! (for example `tools/python/extract_features.py`; `latentam convert
//! --features DIR` finds them by the colour image's file stem `S`):
//! * `S.safetensors` with either
//!   - `labels`: U16 `[H, W]` region index per pixel (65535 = none; I32/I64
//!     with -1 = none are accepted) and `features`: F16/F32 `[N, D]`, one
//!     vector per region; or
//!   - `grid`: F16/F32 `[R, C, D]`, one vector per grid cell (row-major);
//!
//!   and metadata `model` (the embedding model id);
//! * `S.labels.npy` + `S.features.npy` (same shapes and types);
//! * `S.grid.npy`.
//!
//! `.npy` files carry no model id: the caller knows it.

use latentam_base::Result;

use super::tensor::{
    bad, dim_of, floats, labels, npy_tensor, open_safetensors, safetensors_metadata,
    safetensors_tensor, size_u32, Tensor,
};
use crate::codec;

/// Embeddings of one frame.
#[derive(Clone, Debug, PartialEq)]
pub enum FrameFeatures {
    /// One vector per region of a label image.
    Regions {
        /// Label image columns.
        width: u32,
        /// Label image rows.
        height: u32,
        /// Region per pixel, 65535 = none.
        labels: Vec<u16>,
        /// Number of regions.
        count: u32,
        /// `count × dim` values.
        vectors: Vec<f32>,
    },
    /// One vector per grid cell.
    Grid {
        /// Grid rows.
        rows: u32,
        /// Grid columns.
        cols: u32,
        /// `rows × cols × dim` values.
        vectors: Vec<f32>,
    },
}

/// Embeddings of one frame with their dimension and model id.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadedFeatures {
    /// The vectors and their layout.
    pub features: FrameFeatures,
    /// Vector length.
    pub dim: usize,
    /// Embedding model id.
    pub model: String,
}

pub(super) fn regions(l: Tensor, f: Tensor, origin: &str) -> Result<(FrameFeatures, usize)> {
    let [h, w] = l.shape[..] else {
        return Err(bad(
            origin,
            format!("labels have shape {:?}, expected [H, W]", l.shape),
        ));
    };
    let [n, d] = f.shape[..] else {
        return Err(bad(
            origin,
            format!("features have shape {:?}, expected [N, D]", f.shape),
        ));
    };
    if h == 0
        || w == 0
        || h > codec::MAX_IMAGE_SIDE as usize
        || w > codec::MAX_IMAGE_SIDE as usize
        || d == 0
    {
        return Err(bad(
            origin,
            format!("label image {w}×{h} or dimension {d} out of range"),
        ));
    }
    dim_of(d, origin)?;
    let count = size_u32(n, &format!("{origin}: feature row count"))?;
    let labels = labels(&l, &format!("{origin}: labels"))?;
    if let Some(bad_label) = labels.iter().find(|&&x| x != u16::MAX && x as usize >= n) {
        return Err(bad(
            origin,
            format!("region label {bad_label} but only {n} feature rows"),
        ));
    }
    Ok((
        // `w`, `h` are at most MAX_IMAGE_SIDE (checked above).
        FrameFeatures::Regions {
            width: w as u32,
            height: h as u32,
            labels,
            count,
            vectors: floats(&f, &format!("{origin}: features"))?,
        },
        d,
    ))
}

pub(super) fn grid(g: Tensor, origin: &str) -> Result<(FrameFeatures, usize)> {
    let [r, c, d] = g.shape[..] else {
        return Err(bad(
            origin,
            format!("grid has shape {:?}, expected [R, C, D]", g.shape),
        ));
    };
    if r == 0 || c == 0 || d == 0 {
        return Err(bad(origin, format!("empty grid {:?}", g.shape)));
    }
    dim_of(d, origin)?;
    // The ingest takes at most u32::MAX cells in all.
    if r.checked_mul(c)
        .is_none_or(|cells| cells > u32::MAX as usize)
    {
        return Err(bad(origin, format!("grid of {r}×{c} cells is too large")));
    }
    Ok((
        FrameFeatures::Grid {
            // Both fit: their product does.
            rows: r as u32,
            cols: c as u32,
            vectors: floats(&g, &format!("{origin}: grid"))?,
        },
        d,
    ))
}

/// One frame's region embeddings from the bytes of `S.labels.npy` and
/// `S.features.npy` (named `labels_origin` and `features_origin` in
/// errors), and their dimension.
///
/// ```
/// use latentam_io::embedding_files::npy::{self, NpyType};
/// use latentam_io::embedding_files::{regions_from_npy, FrameFeatures};
///
/// // A 2×1 label image: pixel 0 is region 0, pixel 1 none; one 2-d vector.
/// let labels = npy::write(NpyType::U16, &[1, 2], &[0, 0, 0xff, 0xff]);
/// let vector: Vec<u8> = [1f32, 0.0].iter().flat_map(|x| x.to_le_bytes()).collect();
/// let features = npy::write(NpyType::F32, &[1, 2], &vector);
/// let (f, dim) = regions_from_npy(&labels, &features, "S.labels.npy", "S.features.npy")?;
/// assert_eq!(dim, 2);
/// assert!(matches!(f, FrameFeatures::Regions { count: 1, .. }));
/// # Ok::<(), latentam_io::Error>(())
/// ```
pub fn regions_from_npy(
    labels: &[u8],
    features: &[u8],
    labels_origin: &str,
    features_origin: &str,
) -> Result<(FrameFeatures, usize)> {
    regions(
        npy_tensor(labels, labels_origin)?,
        npy_tensor(features, features_origin)?,
        labels_origin,
    )
}

/// One frame's grid embeddings from the bytes of `S.grid.npy`, and their
/// dimension.
pub fn grid_from_npy(bytes: &[u8], origin: &str) -> Result<(FrameFeatures, usize)> {
    grid(npy_tensor(bytes, origin)?, origin)
}

/// One frame's embeddings from the bytes of `S.safetensors`: either
/// `labels` (U16 `[H, W]`, a region index per pixel, 65535 = none; I32/I64
/// with -1 = none are accepted) and `features` (F16/F32 `[N, D]`, one
/// vector per region), or `grid` (F16/F32 `[R, C, D]`, one vector per
/// cell, row-major); the model id is the metadata's `model`, which `model`
/// overrides.
pub fn features_from_safetensors(
    bytes: &[u8],
    origin: &str,
    model: Option<String>,
) -> Result<LoadedFeatures> {
    let st = open_safetensors(bytes, origin)?;
    let file_model = safetensors_metadata(bytes, origin)?.remove("model");
    let (features, dim) = match (
        safetensors_tensor(&st, "labels", origin)?,
        safetensors_tensor(&st, "features", origin)?,
        safetensors_tensor(&st, "grid", origin)?,
    ) {
        (Some(l), Some(f), _) => regions(l, f, origin)?,
        (_, _, Some(g)) => grid(g, origin)?,
        _ => {
            return Err(bad(
                origin,
                "needs tensors `labels` + `features`, or `grid`",
            ))
        }
    };
    let model = model
        .or(file_model)
        .ok_or_else(|| bad(origin, "no `model` in the metadata; pass --model"))?;
    Ok(LoadedFeatures {
        features,
        dim,
        model,
    })
}

#[cfg(test)]
#[path = "features_tests.rs"]
mod tests;
