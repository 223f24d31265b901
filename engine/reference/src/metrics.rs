//! The per-pixel evaluation protocol (paper Sec. IV-A) with every pixel decoded
//! explicitly in f64: the oracle of `latentam_core::mapper::pixel_metrics`.
//! Cosine loss: mean over pixels with a target of 1 − cos(e_p, t). Class
//! of a pixel: the vocabulary entry with the largest ⟨e_p, t̂_c⟩, counted
//! when the pixel's true class is in the vocabulary.

use std::collections::BTreeMap;

use super::decoder::{forward, DecoderShape};

/// Sums of one view, and per class (intersection, union, truth) counts.
///
/// ```
/// use latentam_reference::decoder::DecoderShape;
/// use latentam_reference::metrics::pixel_metrics;
///
/// // One pixel decoded (identity W, one atom) to (0, 1): its region's target
/// // and the text embedding of class 7 ("chair"), not of class 3 ("wall").
/// let shape = DecoderShape { n: 1, query_dim: 2, dim: 2, atoms: 1, tau: 0.1, eps: 1e-12 };
/// let vocabulary = ([3u16, 7], [1.0f32, 0.0, 0.0, 1.0]);
/// let m = pixel_metrics(&shape, &[1.0, 0.0], &[1.0, 0.0, 0.0, 1.0], &[0.0, 1.0],
///     &[0], &[0.0, 1.0], &[7], Some((&vocabulary.0, &vocabulary.1)));
/// assert_eq!(m.cosine_pixels, 1);
/// assert!(m.cosine_loss_sum.abs() < 1e-12);
/// assert_eq!(m.classes[&7], [1, 1, 1]); // intersection, union, true pixels
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Metrics {
    /// Σ 1 − cos over pixels with a target.
    pub cosine_loss_sum: f64,
    /// Pixels with a target.
    pub cosine_pixels: u64,
    /// Per class: intersection, union, true pixels.
    pub classes: BTreeMap<u16, [u64; 3]>,
}

/// The metrics of pixels `queries` (n × d_s) of a view decoded with `w`
/// (d_s × d_f), `d` (K × d_f): `region[p]` indexes `targets` (u32::MAX:
/// none; zero rows have no target), `truth[p]` is the true class (0:
/// none), `vocabulary` the class ids and text embeddings.
#[allow(clippy::too_many_arguments)]
pub fn pixel_metrics(
    shape: &DecoderShape,
    queries: &[f32],
    w: &[f32],
    d: &[f32],
    region: &[u32],
    targets: &[f32],
    truth: &[u16],
    vocabulary: Option<(&[u16], &[f32])>,
) -> Metrics {
    let fwd = forward(shape, queries, w, d);
    let dim = shape.dim;
    let unit = |v: &[f32]| -> Vec<f64> {
        let n = v.iter().map(|&x| x as f64 * x as f64).sum::<f64>().sqrt();
        v.iter()
            .map(|&x| if n > 0.0 { x as f64 / n } else { 0.0 })
            .collect()
    };
    let mut m = Metrics::default();
    for p in 0..shape.n {
        let e = &fwd.output[p * dim..(p + 1) * dim];
        let e_norm = e.iter().map(|x| x * x).sum::<f64>().sqrt();
        let r = region[p];
        if r != u32::MAX {
            let t = unit(&targets[r as usize * dim..(r as usize + 1) * dim]);
            if t.iter().any(|&x| x != 0.0) {
                let cos = e.iter().zip(&t).map(|(a, b)| a * b).sum::<f64>() / e_norm;
                m.cosine_loss_sum += 1.0 - cos;
                m.cosine_pixels += 1;
            }
        }
        let Some((ids, texts)) = vocabulary else {
            continue;
        };
        let t = truth[p];
        if t == 0 || !ids.contains(&t) {
            continue;
        }
        let scores: Vec<f64> = texts
            .chunks_exact(dim)
            .map(|c| unit(c).iter().zip(e).map(|(a, b)| a * b).sum())
            .collect();
        let best = (0..ids.len())
            .max_by(|&a, &b| scores[a].total_cmp(&scores[b]))
            .map(|c| ids[c]);
        let e_t = m.classes.entry(t).or_default();
        e_t[2] += 1;
        e_t[1] += 1;
        match best {
            Some(b) if b == t => e_t[0] += 1,
            Some(b) => m.classes.entry(b).or_default()[1] += 1,
            None => {}
        }
    }
    m
}
