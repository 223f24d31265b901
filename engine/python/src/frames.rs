//! numpy arrays to engine frames and back, every shape and dtype checked
//! (a `BadInputError`, a `ValueError`, that names the argument, what it
//! must be and what it is), with one copy of each image.

use glam::DAffine3;
use half::f16;
use latentam::frames::{
    CameraPose, ColorImage, DepthData, DepthImage, Dtype, EmbeddingLayout, Embeddings, Frame,
    Intrinsics, LabelImage, PixelFormat,
};
use latentam::Camera;
use numpy::{Element, PyArray1, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

fn bad(message: String) -> PyErr {
    crate::errors::BadInputError::new_err(message)
}

/// What `obj` is, for a message: its dtype and shape when it is an array.
fn describe(obj: &Bound<'_, PyAny>) -> String {
    match (obj.getattr("dtype"), obj.getattr("shape")) {
        (Ok(d), Ok(s)) => format!("an array of {d} with shape {s}"),
        _ => format!(
            "a {}",
            obj.get_type().name().map_or("?".into(), |n| n.to_string())
        ),
    }
}

/// `obj` as an array of `T` (exactly that dtype), with its shape.
fn values<T: Element + Copy>(
    obj: &Bound<'_, PyAny>,
    name: &str,
    what: &str,
) -> PyResult<(Vec<T>, Vec<usize>)> {
    let array = obj
        .downcast::<PyArrayDyn<T>>()
        .map_err(|_| bad(format!("{name} must be {what}, not {}", describe(obj))))?;
    let read = array.readonly();
    // One copy: a memcpy for a C-contiguous array, else element by element.
    let values = match read.as_slice() {
        Ok(contiguous) => contiguous.to_vec(),
        Err(_) => read.as_array().iter().copied().collect(),
    };
    Ok((values, read.shape().to_vec()))
}

/// A small matrix (any numeric array or nested sequence), `rows × cols`.
fn matrix(obj: &Bound<'_, PyAny>, name: &str, rows: usize, cols: usize) -> PyResult<Vec<[f64; 4]>> {
    let m: Vec<Vec<f64>> = obj.extract().map_err(|_| {
        bad(format!(
            "{name} must be a {rows}×{cols} matrix of numbers, not {}",
            describe(obj)
        ))
    })?;
    if m.len() != rows || m.iter().any(|r| r.len() != cols) {
        let shape: Vec<usize> = m.iter().map(|r| r.len()).collect();
        return Err(bad(format!(
            "{name} must be {rows}×{cols}; it has {} rows of {shape:?} values",
            m.len()
        )));
    }
    if m.iter().flatten().any(|v| !v.is_finite()) {
        return Err(bad(format!("{name} has values that are not finite")));
    }
    Ok(m.into_iter()
        .map(|r| std::array::from_fn(|j| r.get(j).copied().unwrap_or(0.0)))
        .collect())
}

fn intrinsics(k: &Bound<'_, PyAny>, width: u32, height: u32) -> PyResult<Intrinsics> {
    let k = matrix(k, "K", 3, 3)?;
    let pinhole = k[0][0] > 0.0
        && k[1][1] > 0.0
        && k[0][1] == 0.0
        && k[1][0] == 0.0
        && k[2][0] == 0.0
        && k[2][1] == 0.0
        && k[2][2] == 1.0;
    if !pinhole {
        return Err(bad(format!(
            "K must be a pinhole camera [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, not {:?}",
            k.iter().map(|r| &r[..3]).collect::<Vec<_>>()
        )));
    }
    Ok(Intrinsics {
        width,
        height,
        fx: k[0][0],
        fy: k[1][1],
        cx: k[0][2],
        cy: k[1][2],
    })
}

fn pose(t: &Bound<'_, PyAny>) -> PyResult<CameraPose> {
    let m = matrix(t, "T_world_camera", 4, 4)?;
    let flat: [f64; 16] = std::array::from_fn(|i| m[i / 4][i % 4]);
    CameraPose::from_matrix(&flat).map_err(|why| bad(format!("T_world_camera: {why}")))
}

/// A frame of numpy arrays (see `Mapper.submit`).
#[allow(clippy::too_many_arguments)]
pub fn frame_from_arrays(
    rgb: &Bound<'_, PyAny>,
    depth: &Bound<'_, PyAny>,
    k: &Bound<'_, PyAny>,
    t: &Bound<'_, PyAny>,
    stamp_ns: i64,
    regions: Option<&Bound<'_, PyAny>>,
    embeddings: Option<&Bound<'_, PyAny>>,
    model: &str,
) -> PyResult<Frame> {
    let (rgb, shape) = values::<u8>(rgb, "rgb", "a uint8 array [H, W, 3]")?;
    let [h, w, 3] = shape[..] else {
        return Err(bad(format!("rgb must have shape [H, W, 3], not {shape:?}")));
    };
    if h == 0 || w == 0 || h > 16384 || w > 16384 {
        return Err(bad(format!(
            "rgb is {w}×{h}; images of 1 to 16384 pixels a side are taken"
        )));
    }
    let (width, height) = (w as u32, h as u32);
    let depth = if let Ok((mm, shape)) = values::<u16>(depth, "depth", "") {
        (
            DepthData::Units {
                values: mm,
                metres_per_unit: 0.001,
            },
            shape,
        )
    } else {
        let (m, shape) = values::<f32>(
            depth,
            "depth",
            "a uint16 (millimetres) or float32 (metres) array [H, W]",
        )?;
        let m = m
            .into_iter()
            .map(|z| if z.is_finite() { z } else { 0.0 })
            .collect();
        (DepthData::Metres(m), shape)
    };
    if depth.1 != [h, w] {
        return Err(bad(format!(
            "depth must have the colour image's shape [{h}, {w}], not {:?} (register depth to colour first)",
            depth.1
        )));
    }
    let embeddings = match (regions, embeddings) {
        (None, None) => None,
        (Some(_), None) | (None, Some(_)) => {
            return Err(bad("regions and embeddings come together: a region id image [H, W] and one embedding row per id".into()))
        }
        (Some(r), Some(e)) => Some(region_embeddings(r, e, h, w, model)?),
    };
    let frame = Frame {
        stamp_ns,
        pose: pose(t)?,
        intrinsics: intrinsics(k, width, height)?,
        color: ColorImage {
            width,
            height,
            format: PixelFormat::Rgb8,
            data: rgb,
        },
        depth: DepthImage {
            width,
            height,
            data: depth.0,
        },
        embeddings,
        semantic: None,
    };
    // `Mapper::submit` checks that the frame holds together (sizes, a
    // region without an embedding), raising ValueError.
    Ok(frame)
}

fn region_embeddings(
    regions: &Bound<'_, PyAny>,
    embeddings: &Bound<'_, PyAny>,
    h: usize,
    w: usize,
    model: &str,
) -> PyResult<Embeddings> {
    let (labels, shape) = values::<u16>(regions, "regions", "a uint16 array [H, W] of region ids")?;
    if shape != [h, w] {
        return Err(bad(format!(
            "regions must have shape [{h}, {w}], not {shape:?}"
        )));
    }
    let what = "a float16 or float32 array [N, D], one row per region id";
    let (data, dtype, shape) = if let Ok((v, s)) = values::<f16>(embeddings, "embeddings", what) {
        if v.iter().any(|x| !x.is_finite()) {
            return Err(bad("embeddings have values that are not finite".into()));
        }
        (le_bytes(&v), Dtype::F16, s)
    } else {
        let (v, s) = values::<f32>(embeddings, "embeddings", what)?;
        if v.iter().any(|x| !x.is_finite()) {
            return Err(bad("embeddings have values that are not finite".into()));
        }
        (le_bytes(&v), Dtype::F32, s)
    };
    let [n, d] = shape[..] else {
        return Err(bad(format!(
            "embeddings must have shape [N, D], not {shape:?}"
        )));
    };
    Ok(Embeddings {
        layout: EmbeddingLayout::Regions(LabelImage {
            width: w as u32,
            height: h as u32,
            labels,
        }),
        count: n as u32,
        dim: d as u32,
        dtype,
        data,
        model: model.to_string(),
    })
}

/// Values as the little-endian bytes of an engine buffer.
fn le_bytes<T: bytemuck::Pod>(values: &[T]) -> Vec<u8> {
    #[cfg(target_endian = "little")]
    {
        bytemuck::cast_slice(values).to_vec()
    }
    #[cfg(not(target_endian = "little"))]
    {
        let size = std::mem::size_of::<T>();
        bytemuck::cast_slice::<T, u8>(values)
            .chunks_exact(size)
            .flat_map(|c| c.iter().rev().copied())
            .collect()
    }
}

/// Text embeddings as rows: float32 [D] (one) or [M, D] (several).
pub fn embedding_rows(obj: &Bound<'_, PyAny>) -> PyResult<(Vec<f32>, usize)> {
    let (v, shape) = values::<f32>(obj, "the text embedding", "a float32 array [D] or [M, D]")?;
    let rows = match shape[..] {
        [d] if d > 0 => 1,
        [m, d] if m > 0 && d > 0 => m,
        _ => {
            return Err(bad(format!(
                "a text embedding must have shape [D] or [M, D], not {shape:?}"
            )))
        }
    };
    if v.iter().any(|x| !x.is_finite()) {
        return Err(bad(
            "the text embedding has values that are not finite".into()
        ));
    }
    Ok((v, rows))
}

/// A camera of `width × height` pixels at a pose, with intrinsics `K`.
pub fn camera_from(
    t: &Bound<'_, PyAny>,
    k: &Bound<'_, PyAny>,
    width: u32,
    height: u32,
) -> PyResult<Camera> {
    if width == 0 || height == 0 || width > 16384 || height > 16384 {
        return Err(bad(format!(
            "a {width}×{height} view; 1 to 16384 pixels a side are rendered"
        )));
    }
    let p = pose(t)?;
    let k = intrinsics(k, width, height)?;
    let mut cam = Camera::at_origin(width, height);
    cam.cam_to_world = DAffine3::from_rotation_translation(p.rotation, p.translation);
    cam.fx = k.fx;
    cam.fy = k.fy;
    cam.cx = k.cx;
    cam.cy = k.cy;
    Ok(cam)
}

/// A frame as the keyword arguments of `Mapper.submit`.
pub fn arrays_from_frame<'py>(py: Python<'py>, f: &Frame) -> PyResult<Bound<'py, PyDict>> {
    let (h, w) = (f.color.height as usize, f.color.width as usize);
    let d = PyDict::new(py);
    d.set_item(
        "rgb",
        PyArray1::from_vec(py, f.color.to_rgb8()).reshape(vec![h, w, 3])?,
    )?;
    d.set_item(
        "depth",
        PyArray1::from_vec(py, f.depth.to_metres()).reshape(vec![h, w])?,
    )?;
    let k = &f.intrinsics;
    let km = vec![k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0];
    d.set_item("K", PyArray1::from_vec(py, km).reshape(vec![3, 3])?)?;
    d.set_item(
        "T_world_camera",
        PyArray1::from_vec(py, f.pose.to_matrix().to_vec()).reshape(vec![4, 4])?,
    )?;
    d.set_item("stamp_ns", f.stamp_ns)?;
    if let Some(e) = &f.embeddings {
        if let EmbeddingLayout::Regions(mask) = &e.layout {
            d.set_item(
                "regions",
                PyArray1::from_vec(py, mask.labels.clone()).reshape(vec![h, w])?,
            )?;
            let rows = PyArray1::from_vec(py, e.to_f32())
                .reshape(vec![e.count as usize, e.dim as usize])?;
            d.set_item("embeddings", rows)?;
            d.set_item("model", e.model.clone())?;
        }
    }
    Ok(d)
}
