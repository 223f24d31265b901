//! Per-frame embedding files written by a user's own extractor (for
//! example `tools/python/extract_features.py`), and the readers of `.npy`
//! and safetensors embeddings they share with the oracle and with
//! `query --embedding`.
//!
//! # Per-frame feature files (`--features DIR`)
//! For a colour image with file stem `S` (`frame-000000.color.jpg` → `S` =
//! `frame-000000.color`; the stem without a trailing `.color` is tried
//! too), the first of these found in `DIR` is used:
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
//! For `.npy` files the model id comes from `--model` or `DIR/model.txt`.
//! Frames with no file are written without embeddings and counted.
//!
//! Oracle embeddings for evaluation are in [`super::oracle`].

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use latentam_io::{codec, MAX_EMBEDDING_DIM};

use super::npy::{self, Npy, NpyType};

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

/// File stems a frame's files may have: its image's stem, and that stem
/// without a trailing `.color` (7-Scenes names images `X.color.jpg`).
pub(super) fn candidate_stems(stem: &str) -> impl Iterator<Item = &str> {
    std::iter::once(stem).chain(stem.strip_suffix(".color"))
}

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

pub(super) fn read(path: &Path) -> anyhow::Result<Vec<u8>> {
    latentam_io::read_input(path).with_context(|| format!("reading {}", path.display()))
}

/// `bytes` as a safetensors file whose header names each key once.
pub(super) fn open_safetensors<'a>(
    bytes: &'a [u8],
    origin: &str,
) -> anyhow::Result<safetensors::SafeTensors<'a>> {
    latentam_io::check_safetensors_keys(bytes).map_err(|e| anyhow::anyhow!("{origin}: {e}"))?;
    safetensors::SafeTensors::deserialize(bytes)
        .with_context(|| format!("{origin}: not a safetensors file"))
}

pub(super) fn safetensors_tensor(
    st: &safetensors::SafeTensors<'_>,
    name: &str,
    origin: &str,
) -> anyhow::Result<Option<Tensor>> {
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
            bail!("{origin}: tensor `{name}` has type {other:?} (accepted: U8 U16 I32 I64 F16 F32)")
        }
    };
    Ok(Some(Tensor {
        dtype,
        shape: view.shape().to_vec(),
        data: view.data().to_vec(),
    }))
}

pub(super) fn floats(t: &Tensor, what: &str) -> anyhow::Result<Vec<f32>> {
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
        other => bail!("{what} must be F16 or F32, not {other:?}"),
    };
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        bail!("{what} has a non-finite value at element {i}");
    }
    Ok(v)
}

pub(super) fn labels(t: &Tensor, what: &str) -> anyhow::Result<Vec<u16>> {
    let convert = |v: i64| -> anyhow::Result<u16> {
        match v {
            -1 => Ok(u16::MAX),
            0..=65535 => Ok(v as u16),
            _ => bail!("{what} has label {v} outside -1…65535"),
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
        other => bail!("{what} must be an integer type, not {other:?}"),
    }
}

/// `v` as a `u32`, or an error naming what it is: sizes from a file are
/// written to messages as `u32`s.
fn size_u32(v: usize, what: &str) -> anyhow::Result<u32> {
    u32::try_from(v).map_err(|_| anyhow::anyhow!("{what} {v} is too large"))
}

/// An embedding dimension from a file, checked against what a log may hold.
pub(super) fn dim_of(d: usize, origin: &str) -> anyhow::Result<u32> {
    match u32::try_from(d) {
        Ok(d) if (1..=MAX_EMBEDDING_DIM).contains(&d) => Ok(d),
        _ => bail!("{origin}: embedding dimension {d} is out of range (1…{MAX_EMBEDDING_DIM})"),
    }
}

fn regions(l: Tensor, f: Tensor, origin: &str) -> anyhow::Result<(FrameFeatures, usize)> {
    let [h, w] = l.shape[..] else {
        bail!("{origin}: labels have shape {:?}, expected [H, W]", l.shape);
    };
    let [n, d] = f.shape[..] else {
        bail!(
            "{origin}: features have shape {:?}, expected [N, D]",
            f.shape
        );
    };
    if h == 0
        || w == 0
        || h > codec::MAX_IMAGE_SIDE as usize
        || w > codec::MAX_IMAGE_SIDE as usize
        || d == 0
    {
        bail!("{origin}: label image {w}×{h} or dimension {d} out of range");
    }
    dim_of(d, origin)?;
    let count = size_u32(n, &format!("{origin}: feature row count"))?;
    let labels = labels(&l, &format!("{origin}: labels"))?;
    if let Some(bad) = labels.iter().find(|&&x| x != u16::MAX && x as usize >= n) {
        bail!("{origin}: region label {bad} but only {n} feature rows");
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

fn grid(g: Tensor, origin: &str) -> anyhow::Result<(FrameFeatures, usize)> {
    let [r, c, d] = g.shape[..] else {
        bail!("{origin}: grid has shape {:?}, expected [R, C, D]", g.shape);
    };
    if r == 0 || c == 0 || d == 0 {
        bail!("{origin}: empty grid {:?}", g.shape);
    }
    dim_of(d, origin)?;
    // The ingest takes at most u32::MAX cells in all.
    if r.checked_mul(c)
        .is_none_or(|cells| cells > u32::MAX as usize)
    {
        bail!("{origin}: grid of {r}×{c} cells is too large");
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

/// A folder of per-frame feature files.
pub struct FeatureDir {
    dir: PathBuf,
    model: Option<String>,
}

/// Embeddings of one frame with their dimension and model id.
pub struct LoadedFeatures {
    /// The vectors and their layout.
    pub features: FrameFeatures,
    /// Vector length.
    pub dim: usize,
    /// Embedding model id.
    pub model: String,
}

impl FeatureDir {
    /// Opens `dir`; `model` overrides the model id of every file.
    pub fn new(dir: &Path, model: Option<String>) -> anyhow::Result<Self> {
        if !dir.is_dir() {
            bail!("--features {}: not a directory", dir.display());
        }
        let model = match model {
            Some(m) => Some(m),
            None => latentam_io::read_input_to_string(&dir.join("model.txt"))
                .ok()
                .map(|s| s.trim().to_string()),
        };
        Ok(FeatureDir {
            dir: dir.to_path_buf(),
            model,
        })
    }

    /// The features of the frame with file stem `stem`, `None` if it has
    /// no file.
    pub fn load(&self, stem: &str) -> anyhow::Result<Option<LoadedFeatures>> {
        for s in candidate_stems(stem) {
            let st = self.dir.join(format!("{s}.safetensors"));
            if st.is_file() {
                return self.load_safetensors(&st).map(Some);
            }
            let l = self.dir.join(format!("{s}.labels.npy"));
            let f = self.dir.join(format!("{s}.features.npy"));
            let g = self.dir.join(format!("{s}.grid.npy"));
            let origin = |p: &Path| p.display().to_string();
            let (features, dim) = if l.is_file() && f.is_file() {
                regions_from_npy(&read(&l)?, &read(&f)?, &origin(&l), &origin(&f))?
            } else if g.is_file() {
                grid_from_npy(&read(&g)?, &origin(&g))?
            } else {
                continue;
            };
            let model = self.model.clone().with_context(|| {
                format!(
                    "{}: the model id of .npy features is unknown; pass --model or write model.txt",
                    self.dir.display()
                )
            })?;
            return Ok(Some(LoadedFeatures {
                features,
                dim,
                model,
            }));
        }
        Ok(None)
    }

    fn load_safetensors(&self, path: &Path) -> anyhow::Result<LoadedFeatures> {
        features_from_safetensors(
            &read(path)?,
            &path.display().to_string(),
            self.model.clone(),
        )
    }
}

/// One frame's region embeddings from the bytes of `S.labels.npy` and
/// `S.features.npy` (named `labels_origin` and `features_origin` in
/// errors), and their dimension.
pub fn regions_from_npy(
    labels: &[u8],
    features: &[u8],
    labels_origin: &str,
    features_origin: &str,
) -> anyhow::Result<(FrameFeatures, usize)> {
    regions(
        npy::parse(labels)
            .with_context(|| labels_origin.to_string())?
            .into(),
        npy::parse(features)
            .with_context(|| features_origin.to_string())?
            .into(),
        labels_origin,
    )
}

/// One frame's grid embeddings from the bytes of `S.grid.npy`, and their
/// dimension.
pub fn grid_from_npy(bytes: &[u8], origin: &str) -> anyhow::Result<(FrameFeatures, usize)> {
    grid(
        npy::parse(bytes)
            .with_context(|| origin.to_string())?
            .into(),
        origin,
    )
}

/// One frame's embeddings from the bytes of `S.safetensors` (see the
/// module documentation); `model` overrides the file's model id.
pub fn features_from_safetensors(
    bytes: &[u8],
    origin: &str,
    model: Option<String>,
) -> anyhow::Result<LoadedFeatures> {
    let st = open_safetensors(bytes, origin)?;
    let (_, meta) = safetensors::SafeTensors::read_metadata(bytes)?;
    let file_model = meta
        .metadata()
        .as_ref()
        .and_then(|m| m.get("model").cloned());
    let (features, dim) = match (
        safetensors_tensor(&st, "labels", origin)?,
        safetensors_tensor(&st, "features", origin)?,
        safetensors_tensor(&st, "grid", origin)?,
    ) {
        (Some(l), Some(f), _) => regions(l, f, origin)?,
        (_, _, Some(g)) => grid(g, origin)?,
        _ => bail!("{origin}: needs tensors `labels` + `features`, or `grid`"),
    };
    let model = model
        .or(file_model)
        .with_context(|| format!("{origin}: no `model` in the metadata; pass --model"))?;
    Ok(LoadedFeatures {
        features,
        dim,
        model,
    })
}

/// Reads one embedding vector (e.g. a text embedding to query with) from
/// a `.npy` file (F16/F32, shape `[D]` or `[1, D]`) or a `.safetensors`
/// file holding one such tensor (or several, one named `embedding`).
pub fn read_vector(path: &Path) -> anyhow::Result<Vec<f32>> {
    vector_from_bytes(
        &read(path)?,
        path.extension().is_some_and(|e| e == "safetensors"),
        &path.display().to_string(),
    )
}

/// [`read_vector`] of a file's bytes: `.safetensors` when `safetensors`,
/// `.npy` otherwise; `origin` names the file in errors.
pub fn vector_from_bytes(
    bytes: &[u8],
    safetensors: bool,
    origin: &str,
) -> anyhow::Result<Vec<f32>> {
    let tensor = if safetensors {
        let st = open_safetensors(bytes, origin)?;
        let names = st.names();
        let name = match names.as_slice() {
            [one] => one.to_string(),
            _ if names.contains(&"embedding") => "embedding".to_string(),
            _ => bail!(
                "{origin}: {} tensors ({}); keep one, or name the query `embedding`",
                names.len(),
                names
                    .iter()
                    .map(|n| latentam_base::text::shown(n))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        };
        // `name` is one of `st.names()`, so the tensor exists.
        safetensors_tensor(&st, &name, origin)?.expect("listed above")
    } else {
        Tensor::from(npy::parse(bytes).with_context(|| format!("{origin}: not a .npy array"))?)
    };
    let len = tensor
        .shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .with_context(|| format!("{origin}: shape {:?} overflows", tensor.shape))?;
    if tensor.shape.iter().filter(|&&d| d != 1).count() > 1 || len == 0 {
        bail!(
            "{origin}: shape {:?}; one vector ([D] or [1, D]) is expected",
            tensor.shape
        );
    }
    let v = floats(&tensor, origin)?;
    if v.iter().all(|&x| x == 0.0) {
        bail!("{origin}: the vector is all zeros");
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::convert::oracle::{ClassVectors, Oracle};

    fn tensor(dtype: NpyType, shape: &[usize]) -> Tensor {
        let n: usize = shape.iter().product();
        Tensor {
            dtype,
            shape: shape.to_vec(),
            data: vec![0; n * dtype.size()],
        }
    }

    #[test]
    fn sizes_a_log_cannot_hold_are_errors() {
        // An embedding dimension past the ingest's limit.
        let d = MAX_EMBEDDING_DIM as usize + 1;
        let e = regions(
            tensor(NpyType::U16, &[1, 1]),
            tensor(NpyType::F16, &[1, d]),
            "f",
        )
        .unwrap_err();
        assert!(e.to_string().contains("dimension"), "{e}");
        let e = grid(tensor(NpyType::F16, &[1, 1, d]), "g").unwrap_err();
        assert!(e.to_string().contains("dimension"), "{e}");

        let dir = std::env::temp_dir().join(format!("latentam-oracle-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // More classes than 16-bit class ids can name.
        let vectors = dir.join("vectors.npy");
        let c = u16::MAX as usize + 2;
        std::fs::write(&vectors, npy::write(NpyType::F16, &[c, 1], &vec![0; c * 2])).unwrap();
        let e = Oracle::new(&dir, &vectors).err().unwrap();
        assert!(e.to_string().contains("16-bit"), "{e}");
        // An empty label image.
        std::fs::write(&vectors, npy::write(NpyType::F16, &[2, 1], &[0; 4])).unwrap();
        let oracle = Oracle::new(&dir, &vectors).unwrap();
        std::fs::write(dir.join("f.npy"), npy::write(NpyType::U16, &[0, 3], &[])).unwrap();
        let e = oracle.load("f").err().unwrap();
        assert!(e.to_string().contains("empty"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A safetensors file whose header names a tensor (or the metadata)
    /// twice: other readers would take the first, serde the last.
    #[test]
    fn every_safetensors_reader_refuses_a_key_named_twice() {
        let entry = |name: &str, v: f32| {
            (
                format!(
                    "\"{name}\": {{\"dtype\": \"F32\", \"shape\": [1, 2], \"data_offsets\": [0, 8]}}"
                ),
                [v.to_le_bytes(), 1f32.to_le_bytes()].concat(),
            )
        };
        let file = |entries: &[String], data: &[u8]| {
            let header = format!("{{{}}}", entries.join(", "));
            let mut out = (header.len() as u64).to_le_bytes().to_vec();
            out.extend(header.as_bytes());
            out.extend(data);
            out
        };
        let model = "\"__metadata__\": {\"model\": \"m\"}".to_string();
        for name in ["embedding", "vectors", "grid"] {
            let (e, data) = entry(name, 0.5);
            // Once it reads (where the reader takes such a tensor alone)...
            let once = file(&[e.clone(), model.clone()], &data);
            let twice = file(&[e.clone(), e.clone(), model.clone()], &data);
            let meta_twice = file(&[e, model.clone(), model.clone()], &data);
            fn vector(b: &[u8]) -> anyhow::Result<()> {
                vector_from_bytes(b, true, "f").map(|_| ())
            }
            fn classes(b: &[u8]) -> anyhow::Result<()> {
                ClassVectors::parse(b, true, "f").map(|_| ())
            }
            fn frame(b: &[u8]) -> anyhow::Result<()> {
                features_from_safetensors(b, "f", None).map(|_| ())
            }
            for read in [vector, classes, frame] {
                let _ = read(&once);
                for bad in [&twice, &meta_twice] {
                    let e = read(bad).unwrap_err().to_string();
                    assert!(e.contains("appears twice"), "{name}: {e}");
                }
            }
        }
        // The single files read where their reader takes them.
        let (e, data) = entry("embedding", 0.5);
        assert_eq!(
            vector_from_bytes(&file(&[e], &data), true, "f").unwrap(),
            [0.5, 1.0]
        );
    }
}
