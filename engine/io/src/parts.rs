//! A frame's parts decoded from their messages and checked: intrinsics
//! from camera info, region embeddings from mask features or feature grids.

use super::codec;
use super::frame::{Dtype, EmbeddingLayout, Embeddings, Intrinsics, LabelImage};
use super::messages::{CameraInfo, FeatureGrid, MaskFeatures};
use super::pool::BufferPool;
use latentam_base::Rejection;

/// Refuses intrinsics no real camera has: the principal point outside the
/// image, or a focal length outside 0.05 to 50 image widths (a field of
/// view from about 1° to 170°), the signs of mis-scaled or garbage
/// calibration.
pub(crate) fn check_intrinsics(k: &Intrinsics) -> Result<(), Rejection> {
    let (w, h) = (k.width as f64, k.height as f64);
    let focal = 0.05 * w..=50.0 * w;
    if !(0.0..=w).contains(&k.cx) || !(0.0..=h).contains(&k.cy) {
        return Err(Rejection::new(
            "frame: implausible intrinsics",
            format!(
                "principal point ({}, {}) outside the {}×{} image",
                k.cx, k.cy, k.width, k.height
            ),
        ));
    }
    if !focal.contains(&k.fx) || !focal.contains(&k.fy) {
        return Err(Rejection::new(
            "frame: implausible intrinsics",
            format!(
                "focal length ({}, {}) px outside 0.05 to 50 times the width of {} px",
                k.fx, k.fy, k.width
            ),
        ));
    }
    Ok(())
}

pub(super) fn intrinsics_of(m: &CameraInfo<'_>) -> Result<Intrinsics, Rejection> {
    let [fx, _, cx, _, fy, cy, ..] = m.k;
    if ![fx, fy, cx, cy].iter().all(|v| v.is_finite()) || fx <= 0.0 || fy <= 0.0 {
        return Err(Rejection::new(
            "camera info: invalid intrinsics",
            format!("fx {fx}, fy {fy}, cx {cx}, cy {cy}"),
        ));
    }
    if m.d.iter().any(|c| c != 0.0) {
        return Err(Rejection::new(
            "camera info: distortion not supported",
            format!(
                "`{}` coefficients {:?}; rectify the images first (undistortion is not implemented)",
                m.distortion_model,
                m.d.to_vec()
            ),
        ));
    }
    if m.binning_x > 1 || m.binning_y > 1 || m.roi.0 != [0; 4] {
        return Err(Rejection::new(
            "camera info: binning or ROI not supported",
            format!("binning {}×{}, roi {:?}", m.binning_x, m.binning_y, m.roi.0),
        ));
    }
    Ok(Intrinsics {
        width: m.width,
        height: m.height,
        fx,
        fy,
        cx,
        cy,
    })
}

/// The largest embedding dimension accepted (far beyond any model's; the
/// latent head's buffers are sized by it).
pub const MAX_EMBEDDING_DIM: u32 = 65536;

pub(super) fn check_vectors(
    kind: &'static str,
    count: u64,
    dim: u32,
    dtype: &str,
    len: usize,
) -> Result<Dtype, Rejection> {
    let dt = Dtype::parse(dtype).ok_or_else(|| {
        Rejection::new(
            "embeddings: unknown dtype",
            format!("dtype `{dtype}` (accepted: f16, f32)"),
        )
    })?;
    if dim == 0 {
        return Err(Rejection::new(kind, "dim is 0"));
    }
    if dim > MAX_EMBEDDING_DIM {
        // With no vectors (count 0) any dim matches the empty data; the
        // mapper sizes buffers by it, so it is bounded here.
        return Err(Rejection::new(
            kind,
            format!("dim {dim} is beyond the {MAX_EMBEDDING_DIM} supported"),
        ));
    }
    let need = count
        .saturating_mul(dim as u64)
        .saturating_mul(dt.size() as u64);
    if need != len as u64 {
        return Err(Rejection::new(
            kind,
            format!("{count} vectors × {dim} × {dtype} need {need} bytes, data has {len}"),
        ));
    }
    Ok(dt)
}

pub(super) fn mask_embeddings(
    m: &MaskFeatures<'_>,
    pool: &mut BufferPool,
) -> Result<Embeddings, Rejection> {
    let kind = "embeddings: size mismatch";
    let dtype = check_vectors(kind, m.count as u64, m.dim, m.dtype, m.data.len())?;
    let pixels = m.width as u64 * m.height as u64;
    if pixels == 0
        || pixels > codec::MAX_IMAGE_PIXELS
        || m.width > codec::MAX_IMAGE_SIDE
        || m.height > codec::MAX_IMAGE_SIDE
    {
        return Err(Rejection::new(
            kind,
            format!("label image {}×{}", m.width, m.height),
        ));
    }
    if m.labels.len() as u64 != pixels {
        return Err(Rejection::new(
            kind,
            format!(
                "{} labels for a {}×{} label image",
                m.labels.len(),
                m.width,
                m.height
            ),
        ));
    }
    let labels = pool.copy_words(&m.labels);
    if let Some(&bad) = labels
        .iter()
        .find(|&&l| l != u16::MAX && l as u32 >= m.count)
    {
        pool.recycle_words(labels);
        return Err(Rejection::new(
            "embeddings: label out of range",
            format!("region label {bad} with only {} regions", m.count),
        ));
    }
    Ok(Embeddings {
        layout: EmbeddingLayout::Regions(LabelImage {
            width: m.width,
            height: m.height,
            labels,
        }),
        count: m.count,
        dim: m.dim,
        dtype,
        data: pool.copy_bytes(m.data),
        model: m.model.to_string(),
    })
}

/// Refuses, one by one, region embeddings that hold a NaN or an infinity
/// or are all zero (no direction to learn): their vectors are zeroed, which
/// gives them no weight, and their pixels unlabelled. Returns one
/// rejection per region refused.
pub(super) fn drop_bad_regions(e: &mut Embeddings, stamp: i64) -> Vec<Rejection> {
    let dim = e.dim as usize;
    let row_bytes = dim * e.dtype.size();
    let values = e.to_f32();
    let mut refused = Vec::new();
    let mut bad_ids = Vec::new();
    for (i, (row, v)) in e
        .data
        .chunks_exact_mut(row_bytes.max(1))
        .zip(values.chunks_exact(dim.max(1)))
        .enumerate()
    {
        let (kind, what) = if v.iter().any(|x| !x.is_finite()) {
            (
                "embeddings: region with non-finite values",
                "NaN or infinite values",
            )
        } else if v.iter().all(|&x| x == 0.0) {
            ("embeddings: region with zero norm", "all zeros")
        } else {
            continue;
        };
        row.fill(0);
        bad_ids.push(i as u16);
        refused.push(Rejection::new(
            kind,
            format!("region {i} of {} at {stamp} ns holds {what}", e.count),
        ));
    }
    if let (EmbeddingLayout::Regions(labels), false) = (&mut e.layout, bad_ids.is_empty()) {
        for l in labels.labels.iter_mut() {
            if bad_ids.binary_search(l).is_ok() {
                *l = u16::MAX;
            }
        }
    }
    refused
}

pub(super) fn grid_embeddings(
    m: &FeatureGrid<'_>,
    pool: &mut BufferPool,
) -> Result<Embeddings, Rejection> {
    let cells = m.rows as u64 * m.cols as u64;
    if cells == 0 || cells > u32::MAX as u64 {
        return Err(Rejection::new(
            "embeddings: size mismatch",
            format!("grid of {}×{} cells", m.rows, m.cols),
        ));
    }
    let dtype = check_vectors(
        "embeddings: size mismatch",
        cells,
        m.dim,
        m.dtype,
        m.data.len(),
    )?;
    Ok(Embeddings {
        layout: EmbeddingLayout::Grid {
            rows: m.rows,
            cols: m.cols,
        },
        count: cells as u32,
        dim: m.dim,
        dtype,
        data: pool.copy_bytes(m.data),
        model: m.model.to_string(),
    })
}
