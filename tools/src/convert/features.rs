//! Per-frame embedding files written by a user's own extractor (for
//! example `tools/python/extract_features.py`), and oracle embeddings made
//! from label images and class vectors for evaluation.
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
//! # Oracle embeddings (`--oracle-labels DIR --class-vectors FILE`)
//! `DIR/S.png` (8- or 16-bit grey) or `DIR/S.npy` holds a class id per
//! pixel (0 = unlabelled); `FILE` is a `.npy` `[C, D]` (row c = class c)
//! or a `.safetensors` with `vectors` `[C, D]` and optional metadata
//! `names` (a JSON list) and `model`. Each class present in a frame
//! becomes one region whose target is its class vector; the log is marked
//! `oracle` (model id prefixed `oracle:`), and the label images are also
//! written as semantic ground truth.

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
fn candidate_stems(stem: &str) -> impl Iterator<Item = &str> {
    std::iter::once(stem).chain(stem.strip_suffix(".color"))
}

/// A tensor from either file format.
struct Tensor {
    dtype: NpyType,
    shape: Vec<usize>,
    data: Vec<u8>,
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

fn read(path: &Path) -> anyhow::Result<Vec<u8>> {
    latentam_io::read_input(path).with_context(|| format!("reading {}", path.display()))
}

fn safetensors_tensor(
    st: &safetensors::SafeTensors<'_>,
    name: &str,
    path: &Path,
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
        other => bail!(
            "{}: tensor `{name}` has type {other:?} (accepted: U8 U16 I32 I64 F16 F32)",
            path.display()
        ),
    };
    Ok(Some(Tensor {
        dtype,
        shape: view.shape().to_vec(),
        data: view.data().to_vec(),
    }))
}

fn floats(t: &Tensor, what: &str) -> anyhow::Result<Vec<f32>> {
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

fn labels(t: &Tensor, what: &str) -> anyhow::Result<Vec<u16>> {
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
fn dim_of(d: usize, origin: &str) -> anyhow::Result<u32> {
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
                regions(
                    npy::parse(&read(&l)?).with_context(|| origin(&l))?.into(),
                    npy::parse(&read(&f)?).with_context(|| origin(&f))?.into(),
                    &origin(&l),
                )?
            } else if g.is_file() {
                grid(
                    npy::parse(&read(&g)?).with_context(|| origin(&g))?.into(),
                    &origin(&g),
                )?
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
        let bytes = read(path)?;
        let origin = path.display().to_string();
        let st = safetensors::SafeTensors::deserialize(&bytes)
            .with_context(|| format!("{origin}: not a safetensors file"))?;
        let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes)?;
        let file_model = meta
            .metadata()
            .as_ref()
            .and_then(|m| m.get("model").cloned());
        let (features, dim) = match (
            safetensors_tensor(&st, "labels", path)?,
            safetensors_tensor(&st, "features", path)?,
            safetensors_tensor(&st, "grid", path)?,
        ) {
            (Some(l), Some(f), _) => regions(l, f, &origin)?,
            (_, _, Some(g)) => grid(g, &origin)?,
            _ => bail!("{origin}: needs tensors `labels` + `features`, or `grid`"),
        };
        let model = self
            .model
            .clone()
            .or(file_model)
            .with_context(|| format!("{origin}: no `model` in the metadata; pass --model"))?;
        Ok(LoadedFeatures {
            features,
            dim,
            model,
        })
    }
}

/// One frame's class-id image and the oracle embeddings made from it.
pub struct OracleFrame {
    /// Label image columns.
    pub width: u32,
    /// Label image rows.
    pub height: u32,
    /// Class id per pixel.
    pub classes: Vec<u16>,
    /// One region per class present.
    pub features: FrameFeatures,
}

/// Class vectors and label images for oracle embeddings.
pub struct Oracle {
    labels_dir: PathBuf,
    /// Class names by id.
    pub names: Vec<String>,
    /// Vectors by class id.
    pub vectors: Vec<Vec<f32>>,
    /// Model id, `oracle:` + the file's model (or `class-vectors`).
    pub model: String,
}

impl Oracle {
    /// Loads the class vectors; label images are read per frame.
    pub fn new(labels_dir: &Path, class_vectors: &Path) -> anyhow::Result<Self> {
        if !labels_dir.is_dir() {
            bail!("--oracle-labels {}: not a directory", labels_dir.display());
        }
        let bytes = read(class_vectors)?;
        let origin = class_vectors.display().to_string();
        let (tensor, names, model): (Tensor, Option<Vec<String>>, Option<String>) = if class_vectors
            .extension()
            .is_some_and(|e| e == "safetensors")
        {
            let st = safetensors::SafeTensors::deserialize(&bytes)
                .with_context(|| format!("{origin}: not a safetensors file"))?;
            let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes)?;
            let meta = meta.metadata().clone().unwrap_or_default();
            let names = match meta.get("names") {
                Some(s) => Some(serde_json::from_str(s).with_context(|| {
                    format!("{origin}: metadata `names` is not a JSON list of strings")
                })?),
                None => None,
            };
            let t = safetensors_tensor(&st, "vectors", class_vectors)?
                .with_context(|| format!("{origin}: no tensor `vectors`"))?;
            (t, names, meta.get("model").cloned())
        } else {
            (
                npy::parse(&bytes).with_context(|| origin.clone())?.into(),
                None,
                None,
            )
        };
        let [c, d] = tensor.shape[..] else {
            bail!(
                "{origin}: class vectors have shape {:?}, expected [C, D]",
                tensor.shape
            );
        };
        if c < 2 || d == 0 {
            bail!("{origin}: need at least 2 classes (row 0 is unlabelled) and D > 0");
        }
        // Class ids are u16 in label images and in the vocabulary.
        if c > u16::MAX as usize + 1 {
            bail!(
                "{origin}: {c} class vectors; at most {} (class ids are 16-bit)",
                u16::MAX as usize + 1
            );
        }
        dim_of(d, &origin)?;
        let flat = floats(&tensor, &format!("{origin}: vectors"))?;
        let vectors: Vec<Vec<f32>> = flat.chunks(d).map(|r| r.to_vec()).collect();
        let names = names.unwrap_or_else(|| (0..c).map(|i| format!("class_{i}")).collect());
        if names.len() != c {
            bail!("{origin}: {} names for {c} class vectors", names.len());
        }
        Ok(Oracle {
            labels_dir: labels_dir.to_path_buf(),
            names,
            vectors,
            model: format!("oracle:{}", model.unwrap_or_else(|| "class-vectors".into())),
        })
    }

    /// Embedding dimension.
    pub fn dim(&self) -> usize {
        // `new` requires at least 2 classes.
        self.vectors[0].len()
    }

    /// The class-id image of frame `stem` (`None` if it has none), and its
    /// embeddings: one region per class present.
    pub fn load(&self, stem: &str) -> anyhow::Result<Option<OracleFrame>> {
        for s in candidate_stems(stem) {
            let png = self.labels_dir.join(format!("{s}.png"));
            let npy_path = self.labels_dir.join(format!("{s}.npy"));
            let (w, h, classes) = if png.is_file() {
                codec::decode_png_labels(&read(&png)?)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", png.display()))?
            } else if npy_path.is_file() {
                let t: Tensor = npy::parse(&read(&npy_path)?)
                    .with_context(|| npy_path.display().to_string())?
                    .into();
                let [h, w] = t.shape[..] else {
                    bail!(
                        "{}: shape {:?}, expected [H, W]",
                        npy_path.display(),
                        t.shape
                    );
                };
                let side = 1..=codec::MAX_IMAGE_SIDE as usize;
                if !side.contains(&h) || !side.contains(&w) {
                    bail!(
                        "{}: label image {w}×{h} is empty or beyond {} per side",
                        npy_path.display(),
                        codec::MAX_IMAGE_SIDE
                    );
                }
                (
                    w as u32,
                    h as u32,
                    labels(&t, &npy_path.display().to_string())?,
                )
            } else {
                continue;
            };
            let mut present: Vec<u16> = Vec::new();
            let mut region_of = vec![u16::MAX; self.vectors.len()];
            for &c in &classes {
                if c as usize >= self.vectors.len() {
                    bail!(
                        "{s}: class id {c} but only {} class vectors",
                        self.vectors.len()
                    );
                }
                if c != 0 && region_of[c as usize] == u16::MAX {
                    region_of[c as usize] = present.len() as u16;
                    present.push(c);
                }
            }
            let labels = classes.iter().map(|&c| region_of[c as usize]).collect();
            let vectors = present
                .iter()
                .flat_map(|&c| self.vectors[c as usize].clone())
                .collect();
            let features = FrameFeatures::Regions {
                width: w,
                height: h,
                labels,
                count: present.len() as u32,
                vectors,
            };
            return Ok(Some(OracleFrame {
                width: w,
                height: h,
                classes,
                features,
            }));
        }
        Ok(None)
    }
}

/// Reads one embedding vector (e.g. a text embedding to query with) from
/// a `.npy` file (F16/F32, shape `[D]` or `[1, D]`) or a `.safetensors`
/// file holding one such tensor (or several, one named `embedding`).
pub fn read_vector(path: &Path) -> anyhow::Result<Vec<f32>> {
    let bytes = read(path)?;
    let origin = path.display();
    let tensor = if path.extension().is_some_and(|e| e == "safetensors") {
        let st = safetensors::SafeTensors::deserialize(&bytes)
            .with_context(|| format!("{origin}: not a safetensors file"))?;
        let names = st.names();
        let name = match names.as_slice() {
            [one] => one.to_string(),
            _ if names.contains(&"embedding") => "embedding".to_string(),
            _ => bail!(
                "{origin}: {} tensors ({}); keep one, or name the query `embedding`",
                names.len(),
                names
                    .iter()
                    .map(|n| n.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        };
        // `name` is one of `st.names()`, so the tensor exists.
        safetensors_tensor(&st, &name, path)?.expect("listed above")
    } else {
        Tensor::from(npy::parse(&bytes).with_context(|| format!("{origin}: not a .npy array"))?)
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
    let v = floats(&tensor, &format!("{origin}"))?;
    if v.iter().all(|&x| x == 0.0) {
        bail!("{origin}: the vector is all zeros");
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
