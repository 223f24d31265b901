//! The paper's evaluation protocol on one rendered view (§V, "Performance
//! Metrics"): every pixel's rendered query is decoded (factorised, see
//! [`FactorisedDecoder`]) and
//! * compared with the target embedding of its region: cosine loss
//!   1 − cos(e_p, t_r(p)) over the pixels that have a target;
//! * classified among the vocabulary: the class whose text embedding has
//!   the largest inner product with e_p (the softmax over the vocabulary
//!   keeps that order; texts are unit-normalised), counted against the
//!   pixel's true class when that class is in the vocabulary.
//!
//! CPU reference: `latentam_reference::metrics` (explicit f64 decoding).

use std::collections::BTreeMap;

use super::class_iou::{add_iou, count_pixel, ClassCounts};
use crate::latent::{
    unit_rows, DevicePixelDecoder, FactorisedDecoder, PixelsToDecode, TextOutput, NO_REGION,
};
use crate::splat::QUERY_DIM;
use latentam_base::{Error, Result};
use latentam_gpu::Context;

/// What one view contributes to the per-pixel metrics (sums, so views add).
///
/// ```
/// # use latentam_core::latent::FactorisedDecoder;
/// # use latentam_core::mapper::pixel_metrics::PixelInputs;
/// # let mut w = vec![0.0f32; 32 * 3];
/// # w[0] = 1.0;
/// # let dec = FactorisedDecoder::new(&w, &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0], 3, 0.05, 1e-6)?;
/// # let mut q = [0.0f32; 32];
/// # q[0] = 2.0;
/// # let view = PixelInputs { width: 1, height: 1, queries: &[q], region: &[0],
/// #     targets: &[1.0, 0.0, 0.0], truth: &[0], vocabulary: None, stride: 1 };
/// use latentam_core::mapper::pixel_metrics::{pixel_metrics, PixelMetrics};
///
/// let mut total = PixelMetrics::default();
/// for view in [&view, &view] {
///     total.add(&pixel_metrics(&dec, view)?); // sums, so views add up
/// }
/// assert_eq!(total.cosine_pixels, 2);
/// assert!(total.cosine_loss().unwrap() < 1e-3);
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct PixelMetrics {
    /// Σ over pixels with a target of 1 − cos(e_p, t).
    pub cosine_loss_sum: f64,
    /// Σ over the same pixels of ‖ê_p − t̂‖ = √(2 − 2 cos).
    pub l2_sum: f64,
    /// Pixels with a target.
    pub cosine_pixels: u64,
    /// Per vocabulary class: the masks' pixel counts.
    pub class_iou: BTreeMap<u16, ClassCounts>,
}

impl PixelMetrics {
    /// Mean cosine loss (None without target pixels).
    pub fn cosine_loss(&self) -> Option<f64> {
        (self.cosine_pixels > 0).then(|| self.cosine_loss_sum / self.cosine_pixels as f64)
    }

    /// Mean L2 distance of the unit vectors.
    pub fn l2(&self) -> Option<f64> {
        (self.cosine_pixels > 0).then(|| self.l2_sum / self.cosine_pixels as f64)
    }

    /// Adds `other` into `self`.
    pub fn add(&mut self, other: &PixelMetrics) {
        self.cosine_loss_sum += other.cosine_loss_sum;
        self.l2_sum += other.l2_sum;
        self.cosine_pixels += other.cosine_pixels;
        add_iou(&mut self.class_iou, &other.class_iou);
    }
}

/// A view's per-pixel inputs (row-major, `width` × `height`).
///
/// ```
/// use latentam_core::latent::{FactorisedDecoder, NO_REGION};
/// use latentam_core::mapper::pixel_metrics::{pixel_metrics, PixelInputs};
///
/// // W sends query channel 0 to atom 0 = (1, 0, 0); atom 1 = (0, 1, 0).
/// let mut w = vec![0.0f32; 32 * 3];
/// w[0] = 1.0;
/// let dec = FactorisedDecoder::new(&w, &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0], 3, 0.05, 1e-6)?;
/// let mut q = [0.0f32; 32];
/// q[0] = 2.0;
/// let (ids, texts) = ([5u16, 9], [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0]);
/// let view = PixelInputs {
///     width: 2, height: 1, queries: &[q, q],
///     region: &[0, NO_REGION], targets: &[1.0, 0.0, 0.0], // pixel 1 has no target
///     truth: &[5, 5], vocabulary: Some((&ids[..], &texts[..])), stride: 1,
/// };
/// let m = pixel_metrics(&dec, &view)?;
/// assert_eq!(m.cosine_pixels, 1);
/// assert!(m.cosine_loss().unwrap() < 1e-3);
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct PixelInputs<'a> {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Rendered query of each pixel.
    pub queries: &'a [[f32; QUERY_DIM]],
    /// Region of each pixel ([`NO_REGION`] for none): a row of `targets`.
    pub region: &'a [u32],
    /// Target embedding of each region (regions × d_f; an all-zero row has
    /// no target).
    pub targets: &'a [f32],
    /// True class of each pixel (0: unlabelled).
    pub truth: &'a [u16],
    /// The vocabulary: class ids and their text embeddings (ids × d_f).
    pub vocabulary: Option<(&'a [u16], &'a [f32])>,
    /// Every `stride`-th pixel of every `stride`-th row is evaluated (1:
    /// all).
    pub stride: usize,
}

/// The per-pixel metrics of one view, computed on all CPU cores.
pub fn pixel_metrics(dec: &FactorisedDecoder, v: &PixelInputs) -> Result<PixelMetrics> {
    let dim = dec.dim();
    check_inputs(v, dim)?;
    let (targets, has_target) = unit_rows(v.targets, dim);
    let (ids, texts) = match v.vocabulary {
        Some((ids, texts)) => (ids, dec.project(&unit_rows(texts, dim).0)),
        None => (&[][..], Vec::new()),
    };
    let scored = Scored {
        targets: dec.project(&targets),
        has_target,
        texts,
        ids,
    };
    let stride = v.stride.max(1);
    let rows: Vec<usize> = (0..v.height).step_by(stride).collect();
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(rows.len().max(1));
    let per_thread = rows.len().div_ceil(threads.max(1)).max(1);
    let parts: Vec<PixelMetrics> = std::thread::scope(|s| {
        let handles: Vec<_> = rows
            .chunks(per_thread)
            .map(|chunk| {
                let scored = &scored;
                s.spawn(move || metrics_of_rows(dec, v, scored, chunk, stride))
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
            .collect()
    });
    let mut total = PixelMetrics::default();
    for p in &parts {
        total.add(p);
    }
    Ok(total)
}

/// Errors unless `v`'s per-pixel inputs cover its pixels and hold whole
/// `dim`-d embeddings.
fn check_inputs(v: &PixelInputs, dim: usize) -> Result<()> {
    let n = v.width * v.height;
    let vocab_ok = v
        .vocabulary
        .is_none_or(|(ids, t)| t.len() == ids.len() * dim);
    if v.queries.len() != n
        || v.region.len() != n
        || v.truth.len() != n
        || !v.targets.len().is_multiple_of(dim)
        || !vocab_ok
    {
        return Err(Error::bad_input(
            "per-pixel metrics",
            format!(
                "a {}x{} view with {} queries, {} regions, {} labels, \
             {} target values and a vocabulary of another size for {dim}-d embeddings",
                v.width,
                v.height,
                v.queries.len(),
                v.region.len(),
                v.truth.len(),
                v.targets.len()
            ),
        ));
    }
    Ok(())
}

/// What a view's pixels are scored against, projected onto the atoms once.
struct Scored<'a> {
    /// Each region's unit target, projected (`atoms` values per region).
    targets: Vec<f32>,
    /// Whether a region has a target.
    has_target: Vec<bool>,
    /// Each vocabulary word's unit vector, projected.
    texts: Vec<f32>,
    /// The words' class ids.
    ids: &'a [u16],
}

/// The metrics of the pixels of `rows` (every `stride`-th column): the
/// cosine to its region's target, and the class its decoded embedding is
/// closest to.
fn metrics_of_rows(
    dec: &FactorisedDecoder,
    v: &PixelInputs,
    scored: &Scored<'_>,
    rows: &[usize],
    stride: usize,
) -> PixelMetrics {
    let k = dec.atoms();
    let mut m = PixelMetrics::default();
    let mut a = vec![0.0f32; k];
    let mut used = Vec::new();
    for &y in rows {
        for x in (0..v.width).step_by(stride) {
            let p = y * v.width + x;
            let (target, classify) = pixel_role(v, p, &scored.has_target, scored.ids);
            let truth = v.truth[p];
            if target.is_none() && !classify {
                continue;
            }
            dec.attention(&v.queries[p], &mut a);
            let cosine = target.map(|r| {
                let norm = dec.norm(&a, &mut used) as f64;
                let dot = FactorisedDecoder::dot(&a, &scored.targets[r * k..(r + 1) * k]);
                cosine_of(dot as f64, norm)
            });
            let class = classify.then(|| {
                let best = (0..scored.ids.len())
                    .map(|c| FactorisedDecoder::dot(&a, &scored.texts[c * k..(c + 1) * k]))
                    .enumerate()
                    .max_by(|x, y| x.1.total_cmp(&y.1))
                    .map(|(c, _)| scored.ids[c]);
                (truth, best)
            });
            add_pixel(&mut m, cosine, class);
        }
    }
    m
}

/// What pixel `p` of `v` is evaluated for: the row of its region's target
/// (a region with a target), and whether it is classified (a true class
/// the vocabulary `ids` names). Neither: the pixel is left out.
fn pixel_role(
    v: &PixelInputs,
    p: usize,
    has_target: &[bool],
    ids: &[u16],
) -> (Option<usize>, bool) {
    let r = v.region[p];
    let target =
        (r != NO_REGION && has_target.get(r as usize) == Some(&true)).then_some(r as usize);
    let truth = v.truth[p];
    (target, truth != 0 && ids.contains(&truth))
}

/// ⟨e, t̂⟩ / ‖e‖ (0 for a zero embedding).
fn cosine_of(dot: f64, norm: f64) -> f64 {
    if norm > 0.0 {
        (dot / norm).clamp(-1.0, 1.0)
    } else {
        0.0
    }
}

/// Adds one pixel: its cosine to its region's target, if it has one, and
/// its true and predicted class, if it is classified.
fn add_pixel(m: &mut PixelMetrics, cosine: Option<f64>, class: Option<(u16, Option<u16>)>) {
    if let Some(cos) = cosine {
        m.cosine_loss_sum += 1.0 - cos;
        m.l2_sum += (2.0 - 2.0 * cos).max(0.0).sqrt();
        m.cosine_pixels += 1;
    }
    if let Some((truth, best)) = class {
        count_pixel(&mut m.class_iou, truth, best);
    }
}

/// The per-pixel metrics of one view as [`pixel_metrics`] computes them,
/// decoded on the device ([`DevicePixelDecoder`]): the same pixels, the
/// same rules, within the decoders' rounding.
pub fn pixel_metrics_on_device(
    ctx: &Context,
    dec: &mut DevicePixelDecoder,
    v: &PixelInputs,
) -> Result<PixelMetrics> {
    let dim = dec.dim() as usize;
    check_inputs(v, dim)?;
    let (_, has_target) = unit_rows(v.targets, dim);
    let (ids, texts) = v.vocabulary.unwrap_or((&[], &[]));
    // The evaluated pixels, as pixel_metrics picks them.
    let stride = v.stride.max(1);
    let mut picked = Vec::new();
    let mut region = Vec::new();
    for y in (0..v.height).step_by(stride) {
        for x in (0..v.width).step_by(stride) {
            let p = y * v.width + x;
            let (target, classify) = pixel_role(v, p, &has_target, ids);
            if target.is_some() || classify {
                picked.push((p, classify));
                region.push(target.map_or(NO_REGION, |r| r as u32));
            }
        }
    }
    let queries: Vec<[f32; QUERY_DIM]> = picked.iter().map(|&(p, _)| v.queries[p]).collect();
    let decoded = dec.decode(
        ctx,
        &PixelsToDecode {
            queries: &queries,
            region: &region,
            targets: v.targets,
            texts,
            text_output: TextOutput::Best,
        },
    )?;
    let mut m = PixelMetrics::default();
    for (i, &(p, classify)) in picked.iter().enumerate() {
        let cosine = (region[i] != NO_REGION)
            .then(|| cosine_of(decoded.target_dot[i] as f64, decoded.norm[i] as f64));
        let class = classify.then(|| {
            (
                v.truth[p],
                decoded.best_text.get(i).map(|&c| ids[c as usize]),
            )
        });
        add_pixel(&mut m, cosine, class);
    }
    Ok(m)
}

#[cfg(test)]
#[path = "pixel_metrics_tests.rs"]
mod tests;
