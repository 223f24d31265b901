//! The pixels to decode and what they decode to, and the checks and unit
//! rows of what comes with them.

use crate::latent::NO_REGION;
use crate::splat::QUERY_DIM;
use latentam_base::{Error, Result};

/// What [`DevicePixelDecoder::decode`](super::DevicePixelDecoder::decode)
/// reports about the texts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TextOutput {
    /// Each pixel's ⟨e, t̂_c⟩ for every text c (pixels × texts).
    All,
    /// Only the index of the text with the largest ⟨e, t̂_c⟩ (the largest
    /// cosine: ‖e‖ is the same for every text).
    Best,
}

/// The pixels to decode and what to compare them with.
///
/// ```
/// use latentam_core::latent::{PixelsToDecode, TextOutput, NO_REGION};
///
/// let queries = vec![[0.0f32; 32]; 2];
/// let pixels = PixelsToDecode {
///     queries: &queries,
///     region: &[0, NO_REGION],    // pixel 1 lies in no region
///     targets: &[1.0, 0.0, 0.0],  // region 0's target (3-d embeddings)
///     texts: &[],                 // no texts: no text output
///     text_output: TextOutput::Best,
/// };
/// assert_eq!(pixels.queries.len(), pixels.region.len());
/// ```
#[derive(Clone, Copy, Debug)]
pub struct PixelsToDecode<'a> {
    /// Each pixel's rendered query.
    pub queries: &'a [[f32; QUERY_DIM]],
    /// Each pixel's region, a row of `targets` ([`NO_REGION`]: none);
    /// empty when no pixel has a target.
    pub region: &'a [u32],
    /// Each region's target embedding (regions × d_f, any length; scaled
    /// to unit length here).
    pub targets: &'a [f32],
    /// Text embeddings (texts × d_f, any length; scaled to unit length
    /// here); empty for none.
    pub texts: &'a [f32],
    /// What to report about the texts.
    pub text_output: TextOutput,
}

/// What each pixel decodes to (one entry per pixel unless stated).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DecodedPixels {
    /// ‖e‖.
    pub norm: Vec<f32>,
    /// ⟨e, t̂⟩ with the unit target of the pixel's region (0 without one).
    pub target_dot: Vec<f32>,
    /// With [`TextOutput::All`]: ⟨e, t̂_c⟩, pixels × texts, row-major.
    pub text_dots: Vec<f32>,
    /// With [`TextOutput::Best`]: the index of the best text.
    pub best_text: Vec<u32>,
}

/// Rows of `dim` values scaled to unit length (in f64), and which had a
/// length to scale (a zero or non-finite row stays as zeros and is not).
pub(crate) fn unit_rows(rows: &[f32], dim: usize) -> (Vec<f32>, Vec<bool>) {
    let mut out = Vec::with_capacity(rows.len());
    let mut valid = Vec::with_capacity(rows.len() / dim.max(1));
    for r in rows.chunks_exact(dim) {
        let n = r.iter().map(|&x| x as f64 * x as f64).sum::<f64>().sqrt();
        valid.push(n > 0.0 && n.is_finite());
        let s = if n > 0.0 { 1.0 / n } else { 0.0 };
        out.extend(r.iter().map(|&x| (x as f64 * s) as f32));
    }
    (out, valid)
}

/// Checks `pixels` against a decoder of `dim`-d embeddings: region
/// indices for every pixel (or none), whole embeddings, regions within
/// the targets, finite values. Returns the number of targets.
pub(super) fn check_pixels(pixels: &PixelsToDecode, dim: usize) -> Result<usize> {
    let n = pixels.queries.len();
    if !pixels.region.is_empty() && pixels.region.len() != n {
        return Err(Error::bad_input(
            "pixels to decode",
            format!("{n} pixels with {} region indices", pixels.region.len()),
        ));
    }
    if !pixels.targets.len().is_multiple_of(dim) || !pixels.texts.len().is_multiple_of(dim) {
        return Err(Error::bad_input(
            "pixels to decode",
            format!(
                "{} target and {} text values are not whole {dim}-d embeddings",
                pixels.targets.len(),
                pixels.texts.len()
            ),
        ));
    }
    let regions = pixels.targets.len() / dim;
    if let Some(r) = pixels
        .region
        .iter()
        .find(|&&r| r != NO_REGION && r as usize >= regions)
    {
        return Err(Error::bad_input(
            "pixels to decode",
            format!("a pixel of region {r}; {regions} targets were given"),
        ));
    }
    if pixels
        .queries
        .iter()
        .flatten()
        .chain(pixels.targets)
        .chain(pixels.texts)
        .any(|x| !x.is_finite())
    {
        return Err(Error::bad_input(
            "pixels to decode",
            "pixel queries, targets and texts must be finite",
        ));
    }
    Ok(regions)
}
