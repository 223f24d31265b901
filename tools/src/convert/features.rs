//! Per-frame embedding files written by a user's own extractor (for
//! example `tools/python/extract_features.py`), found in a folder by the
//! colour image's file stem; the readers of the files themselves are the
//! library's (`latentam::embedding_files`), shared with the oracle and with
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
use latentam::embedding_files::{
    features_from_safetensors, grid_from_npy, regions_from_npy, LoadedFeatures,
};

/// File stems a frame's files may have: its image's stem, and that stem
/// without a trailing `.color` (7-Scenes names images `X.color.jpg`).
pub(super) fn candidate_stems(stem: &str) -> impl Iterator<Item = &str> {
    std::iter::once(stem).chain(stem.strip_suffix(".color"))
}

pub(super) fn read(path: &Path) -> anyhow::Result<Vec<u8>> {
    latentam::files::read_input(path).with_context(|| format!("reading {}", path.display()))
}

/// A file the library's readers refused, as the tool says it: the
/// library's message, which names the file (`BadInput` or `Damaged`).
pub(super) fn refused(e: latentam::Error) -> anyhow::Error {
    e.into()
}

/// A folder of per-frame feature files.
pub struct FeatureDir {
    dir: PathBuf,
    model: Option<String>,
}

impl FeatureDir {
    /// Opens `dir`; `model` overrides the model id of every file.
    pub fn new(dir: &Path, model: Option<String>) -> anyhow::Result<Self> {
        if !dir.is_dir() {
            bail!("--features {}: not a directory", dir.display());
        }
        let model = match model {
            Some(m) => Some(m),
            None => latentam::files::read_input_to_string(&dir.join("model.txt"))
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
                regions_from_npy(&read(&l)?, &read(&f)?, &origin(&l), &origin(&f))
                    .map_err(refused)?
            } else if g.is_file() {
                grid_from_npy(&read(&g)?, &origin(&g)).map_err(refused)?
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
        .map_err(refused)
    }
}
