//! What oracle embeddings are made from (`latentam convert --oracle-labels
//! DIR --class-vectors FILE`, for evaluation): class vectors, one row per
//! class id, and class-id images as `.npy` arrays.

use latentam_base::Result;

use super::tensor::{
    bad, dim_of, floats, labels, npy_tensor, open_safetensors, safetensors_metadata,
    safetensors_tensor, Tensor,
};
use crate::codec;

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
    ///
    /// ```
    /// use latentam_io::embedding_files::npy::{self, NpyType};
    /// use latentam_io::embedding_files::ClassVectors;
    ///
    /// let rows: Vec<u8> = [0f32, 0.0, 1.0, 0.0].iter().flat_map(|x| x.to_le_bytes()).collect();
    /// let classes = ClassVectors::parse(&npy::write(NpyType::F32, &[2, 2], &rows), false, "c.npy")?;
    /// assert_eq!(classes.names, ["class_0", "class_1"]);
    /// assert_eq!(classes.model, "oracle:class-vectors");
    /// # Ok::<(), latentam_io::Error>(())
    /// ```
    pub fn parse(bytes: &[u8], safetensors: bool, origin: &str) -> Result<Self> {
        let (tensor, names, model): (Tensor, Option<Vec<String>>, Option<String>) = if safetensors {
            let st = open_safetensors(bytes, origin)?;
            let mut meta = safetensors_metadata(bytes, origin)?;
            let names = match meta.get("names") {
                Some(s) => Some(serde_json::from_str(s).map_err(|e| {
                    bad(
                        origin,
                        format!("metadata `names` is not a JSON list of strings: {e}"),
                    )
                })?),
                None => None,
            };
            let t = safetensors_tensor(&st, "vectors", origin)?
                .ok_or_else(|| bad(origin, "no tensor `vectors`"))?;
            (t, names, meta.remove("model"))
        } else {
            (npy_tensor(bytes, origin)?, None, None)
        };
        let [c, d] = tensor.shape[..] else {
            return Err(bad(
                origin,
                format!(
                    "class vectors have shape {:?}, expected [C, D]",
                    tensor.shape
                ),
            ));
        };
        if c < 2 || d == 0 {
            return Err(bad(
                origin,
                "need at least 2 classes (row 0 is unlabelled) and D > 0",
            ));
        }
        // Class ids are u16 in label images and in the vocabulary.
        if c > u16::MAX as usize + 1 {
            return Err(bad(
                origin,
                format!(
                    "{c} class vectors; at most {} (class ids are 16-bit)",
                    u16::MAX as usize + 1
                ),
            ));
        }
        dim_of(d, origin)?;
        let flat = floats(&tensor, &format!("{origin}: vectors"))?;
        let vectors: Vec<Vec<f32>> = flat.chunks(d).map(|r| r.to_vec()).collect();
        let names = names.unwrap_or_else(|| (0..c).map(|i| format!("class_{i}")).collect());
        if names.len() != c {
            return Err(bad(
                origin,
                format!("{} names for {c} class vectors", names.len()),
            ));
        }
        Ok(ClassVectors {
            names,
            vectors,
            model: format!("oracle:{}", model.unwrap_or_else(|| "class-vectors".into())),
        })
    }
}

/// A class-id image from the bytes of a `.npy` `[H, W]` array of integers
/// (0 = unlabelled; -1 in a signed type reads as 65535): its width, height
/// and class id per pixel, as [`codec::decode_png_labels`] gives those of
/// a PNG. `origin` names the file in errors.
pub fn class_ids_from_npy(bytes: &[u8], origin: &str) -> Result<(u32, u32, Vec<u16>)> {
    let t = npy_tensor(bytes, origin)?;
    let [h, w] = t.shape[..] else {
        return Err(bad(origin, format!("shape {:?}, expected [H, W]", t.shape)));
    };
    let side = 1..=codec::MAX_IMAGE_SIDE as usize;
    if !side.contains(&h) || !side.contains(&w) {
        return Err(bad(
            origin,
            format!(
                "label image {w}×{h} is empty or beyond {} per side",
                codec::MAX_IMAGE_SIDE
            ),
        ));
    }
    // Both at most MAX_IMAGE_SIDE (checked above).
    Ok((w as u32, h as u32, labels(&t, origin)?))
}

#[cfg(test)]
#[path = "class_vectors_tests.rs"]
mod tests;
