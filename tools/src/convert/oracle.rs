//! Oracle embeddings, made from label images and class vectors, for
//! evaluation.
//!
//! With `--oracle-labels DIR --class-vectors FILE`:
//! `DIR/S.png` (8- or 16-bit grey) or `DIR/S.npy` holds a class id per
//! pixel (0 = unlabelled); `FILE` is a `.npy` `[C, D]` (row c = class c)
//! or a `.safetensors` with `vectors` `[C, D]` and optional metadata
//! `names` (a JSON list) and `model`. Each class present in a frame
//! becomes one region whose target is its class vector; the log is marked
//! `oracle` (model id prefixed `oracle:`), and the label images are also
//! written as semantic ground truth.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use latentam_io::codec;

use super::features::{
    candidate_stems, dim_of, floats, labels, open_safetensors, read, safetensors_tensor,
    FrameFeatures, Tensor,
};
use super::npy;

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

/// The class vectors of `--class-vectors`: one row per class id.
#[derive(Debug)]
pub struct ClassVectors {
    /// Class names by id (`class_<id>` where the file names none).
    pub names: Vec<String>,
    /// Vectors by class id, at least 2 (row 0 is unlabelled), all of one
    /// dimension.
    pub vectors: Vec<Vec<f32>>,
    /// Model id, `oracle:` + the file's model (or `class-vectors`).
    pub model: String,
}

impl ClassVectors {
    /// Reads the bytes of a `.npy` `[C, D]` file, or of a `.safetensors`
    /// one (`safetensors` true) with `vectors` `[C, D]` and optional
    /// metadata `names` (a JSON list) and `model`; `origin` names the file
    /// in errors.
    pub fn parse(bytes: &[u8], safetensors: bool, origin: &str) -> anyhow::Result<Self> {
        let (tensor, names, model): (Tensor, Option<Vec<String>>, Option<String>) = if safetensors {
            let st = open_safetensors(bytes, origin)?;
            let (_, meta) = safetensors::SafeTensors::read_metadata(bytes)?;
            let meta = meta.metadata().clone().unwrap_or_default();
            let names = match meta.get("names") {
                Some(s) => Some(serde_json::from_str(s).with_context(|| {
                    format!("{origin}: metadata `names` is not a JSON list of strings")
                })?),
                None => None,
            };
            let t = safetensors_tensor(&st, "vectors", origin)?
                .with_context(|| format!("{origin}: no tensor `vectors`"))?;
            (t, names, meta.get("model").cloned())
        } else {
            (
                npy::parse(bytes)
                    .with_context(|| origin.to_string())?
                    .into(),
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
        dim_of(d, origin)?;
        let flat = floats(&tensor, &format!("{origin}: vectors"))?;
        let vectors: Vec<Vec<f32>> = flat.chunks(d).map(|r| r.to_vec()).collect();
        let names = names.unwrap_or_else(|| (0..c).map(|i| format!("class_{i}")).collect());
        if names.len() != c {
            bail!("{origin}: {} names for {c} class vectors", names.len());
        }
        Ok(ClassVectors {
            names,
            vectors,
            model: format!("oracle:{}", model.unwrap_or_else(|| "class-vectors".into())),
        })
    }
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
        let classes = ClassVectors::parse(
            &read(class_vectors)?,
            class_vectors
                .extension()
                .is_some_and(|e| e == "safetensors"),
            &class_vectors.display().to_string(),
        )?;
        Ok(Oracle {
            labels_dir: labels_dir.to_path_buf(),
            names: classes.names,
            vectors: classes.vectors,
            model: classes.model,
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
