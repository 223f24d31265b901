//! Frames as C structs ([`LatentamFrame`]) and their checked conversion
//! into the engine's frames (rows copied, strides and sizes checked).

use latentam::frames::{
    CameraPose, ColorImage, DepthData, DepthImage, Dtype, EmbeddingLayout, Embeddings, Frame,
    Intrinsics, LabelImage, PixelFormat,
};

use std::ffi::c_char;

use crate::status::{fail, text, LatentamStatus};

/// One RGB-D frame, as the caller holds it: nothing is owned, everything
/// is copied by `latentam_submit`.
#[repr(C)]
pub struct LatentamFrame {
    /// The frame's time, nanoseconds.
    pub stamp_ns: i64,
    /// Image columns.
    pub width: u32,
    /// Image rows.
    pub height: u32,
    /// RGB8 pixels: `height` rows of `rgb_stride` bytes (0: `width * 3`).
    pub rgb: *const u8,
    /// Bytes from one row of `rgb` to the next (0: packed).
    pub rgb_stride: usize,
    /// Depth in millimetres (0: none), or NULL when `depth_m` is given.
    pub depth_mm: *const u16,
    /// Depth in metres (0 or NaN: none), or NULL when `depth_mm` is given.
    pub depth_m: *const f32,
    /// Bytes from one row of depth to the next (0: packed).
    pub depth_stride: usize,
    /// Pinhole intrinsics, row-major 3×3: `[fx, 0, cx, 0, fy, cy, 0, 0, 1]`.
    pub k: [f64; 9],
    /// Camera-to-world transform, row-major 4×4, rigid (camera axes: x
    /// right, y down, z forward).
    pub t_world_camera: [f64; 16],
    /// Region ids (65535: none), `height` rows of `regions_stride` bytes,
    /// or NULL for a frame without embeddings.
    pub regions: *const u16,
    /// Bytes from one row of `regions` to the next (0: packed).
    pub regions_stride: usize,
    /// `embedding_count × embedding_dim` floats, one row per region id, or
    /// NULL.
    pub embeddings: *const f32,
    /// Rows of `embeddings`.
    pub embedding_count: u32,
    /// Columns of `embeddings`.
    pub embedding_dim: u32,
    /// The embedding model's id (NULL: "unknown").
    pub model: *const c_char,
}

/// Copies `height` rows of `width` elements, `stride` bytes apart.
///
/// # Safety
/// `p` points to `height` rows of at least `stride` bytes.
pub(crate) unsafe fn rows<T: Copy>(
    p: *const T,
    width: usize,
    height: usize,
    stride: usize,
) -> Vec<T> {
    let row_bytes = width * std::mem::size_of::<T>();
    let stride = if stride == 0 { row_bytes } else { stride };
    let mut out = Vec::with_capacity(width * height);
    for r in 0..height {
        // SAFETY: the caller's rows; `stride` is a multiple of the element
        // alignment (checked by the caller of `rows`).
        let row = unsafe {
            std::slice::from_raw_parts((p as *const u8).add(r * stride) as *const T, width)
        };
        out.extend_from_slice(row);
    }
    out
}

fn stride_ok<T>(stride: usize, width: usize) -> bool {
    stride == 0
        || (stride >= width * std::mem::size_of::<T>()
            && stride.is_multiple_of(std::mem::align_of::<T>()))
}

/// # Safety
/// The frame's pointers are as documented on [`LatentamFrame`].
pub(crate) unsafe fn frame_of(f: &LatentamFrame) -> Result<Frame, LatentamStatus> {
    let bad = |m: String| Err(fail(LatentamStatus::BadFrame, m));
    let (w, h) = (f.width as usize, f.height as usize);
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return bad(format!(
            "a {w}×{h} frame; 1 to 16384 pixels a side are taken"
        ));
    }
    if f.rgb.is_null() || (f.depth_mm.is_null() == f.depth_m.is_null()) {
        return bad("a frame needs rgb and exactly one of depth_mm and depth_m".into());
    }
    let depth_ok = if f.depth_mm.is_null() {
        stride_ok::<f32>(f.depth_stride, w)
    } else {
        stride_ok::<u16>(f.depth_stride, w)
    };
    let regions_ok = f.regions.is_null() || stride_ok::<u16>(f.regions_stride, w);
    if !stride_ok::<u8>(f.rgb_stride, w * 3) || !depth_ok || !regions_ok {
        return bad(
            "a row stride shorter than a row, or not a multiple of the element size".into(),
        );
    }
    // SAFETY: the caller's buffers, of the sizes the frame states.
    let rgb = unsafe { rows(f.rgb, w * 3, h, f.rgb_stride) };
    let depth = if f.depth_mm.is_null() {
        // SAFETY: as above.
        let m = unsafe { rows(f.depth_m, w, h, f.depth_stride) };
        DepthData::Metres(
            m.into_iter()
                .map(|z| if z.is_finite() { z } else { 0.0 })
                .collect(),
        )
    } else {
        // SAFETY: as above.
        DepthData::Units {
            values: unsafe { rows(f.depth_mm, w, h, f.depth_stride) },
            metres_per_unit: 0.001,
        }
    };
    let k = f.k;
    if [k[1], k[3], k[6], k[7]] != [0.0; 4] || k[8] != 1.0 || !(k[0] > 0.0 && k[4] > 0.0) {
        return bad(format!(
            "k must be a pinhole camera [fx, 0, cx, 0, fy, cy, 0, 0, 1] with fx, fy > 0, not {k:?}"
        ));
    }
    let pose = match CameraPose::from_matrix(&f.t_world_camera) {
        Ok(p) => p,
        Err(why) => return bad(why),
    };
    // SAFETY: the caller's buffers, as above.
    let embeddings = unsafe { embeddings_of(f)? };
    Ok(Frame {
        stamp_ns: f.stamp_ns,
        pose,
        intrinsics: Intrinsics {
            width: f.width,
            height: f.height,
            fx: k[0],
            fy: k[4],
            cx: k[2],
            cy: k[5],
        },
        color: ColorImage {
            width: f.width,
            height: f.height,
            format: PixelFormat::Rgb8,
            data: rgb,
        },
        depth: DepthImage {
            width: f.width,
            height: f.height,
            data: depth,
        },
        embeddings,
        semantic: None,
    })
}

/// The frame's region embeddings, if it has them.
///
/// # Safety
/// As [`frame_of`].
pub(crate) unsafe fn embeddings_of(
    f: &LatentamFrame,
) -> Result<Option<Embeddings>, LatentamStatus> {
    let bad = |m: String| Err(fail(LatentamStatus::BadFrame, m));
    match (f.regions.is_null(), f.embeddings.is_null()) {
        (true, true) => return Ok(None),
        (false, false) => {}
        _ => return bad("regions and embeddings come together, or not at all".into()),
    }
    let model = if f.model.is_null() {
        "unknown".to_string()
    } else {
        // SAFETY: the caller's string.
        unsafe { text(f.model, "model") }?.to_string()
    };
    let (n, d) = (f.embedding_count as usize, f.embedding_dim as usize);
    if n == 0 || d == 0 {
        return bad(format!("{n} embeddings of {d} values"));
    }
    let (w, h) = (f.width as usize, f.height as usize);
    // SAFETY: the caller's `height` rows of region ids.
    let labels = unsafe { rows(f.regions, w, h, f.regions_stride) };
    // SAFETY: the caller's `n × d` floats.
    let values = unsafe { std::slice::from_raw_parts(f.embeddings, n * d) };
    Ok(Some(Embeddings {
        layout: EmbeddingLayout::Regions(LabelImage {
            width: f.width,
            height: f.height,
            labels,
        }),
        count: n as u32,
        dim: d as u32,
        dtype: Dtype::F32,
        data: values.iter().flat_map(|x| x.to_le_bytes()).collect(),
        model,
    }))
}
