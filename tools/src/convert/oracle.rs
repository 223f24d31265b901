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

use anyhow::bail;
use latentam::embedding_files::{class_ids_from_npy, ClassVectors, FrameFeatures};
use latentam::messages::codec;

use super::features::{candidate_stems, read, refused};

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
        let classes = ClassVectors::parse(
            &read(class_vectors)?,
            class_vectors
                .extension()
                .is_some_and(|e| e == "safetensors"),
            &class_vectors.display().to_string(),
        )
        .map_err(refused)?;
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
                class_ids_from_npy(&read(&npy_path)?, &npy_path.display().to_string())
                    .map_err(refused)?
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

#[cfg(test)]
mod tests {
    use super::*;
    use latentam::embedding_files::npy::{self, NpyType};

    #[test]
    fn files_the_readers_refuse_are_errors_naming_the_file() {
        let dir = std::env::temp_dir().join(format!("latentam-oracle-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // More classes than 16-bit class ids can name.
        let vectors = dir.join("vectors.npy");
        let c = u16::MAX as usize + 2;
        std::fs::write(&vectors, npy::write(NpyType::F16, &[c, 1], &vec![0; c * 2])).unwrap();
        let e = Oracle::new(&dir, &vectors).err().unwrap().to_string();
        assert!(
            e.starts_with(&format!("{}: ", vectors.display())) && e.contains("16-bit"),
            "{e}"
        );
        // An empty label image.
        std::fs::write(&vectors, npy::write(NpyType::F16, &[2, 1], &[0; 4])).unwrap();
        let oracle = Oracle::new(&dir, &vectors).unwrap();
        std::fs::write(dir.join("f.npy"), npy::write(NpyType::U16, &[0, 3], &[])).unwrap();
        let e = oracle.load("f").err().unwrap().to_string();
        assert!(
            e.starts_with(dir.to_str().unwrap()) && e.contains("empty"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
