//! Decoding queries to embeddings on the host, in f64, for programs that
//! read an exported map without a GPU (see `mapper::DecoderFile`). The GPU
//! decoders are [`super::AttentionDecoder`] (training) and
//! [`super::FactorisedDecoder`] (per-pixel evaluation); CPU reference:
//! `latentam_reference::decoder::forward`.

use crate::splat::QUERY_DIM;

/// A decoder's parameters, borrowed: `E = qW`, cosine similarity of `E`
/// with every atom, softmax at `temperature`, weighted sum of the atoms
/// (paper Eq. 5).
///
/// ```
/// use latentam_core::latent::HostDecoder;
///
/// // d_f = 2, two atoms; W maps query entry 0 to the first axis.
/// let mut w = vec![0.0f32; 32 * 2];
/// w[0] = 1.0;
/// let atoms = [1.0f32, 0.0, 0.0, 1.0];
/// let decoder = HostDecoder { dim: 2, w: &w, atoms: &atoms, temperature: 0.1, eps: 1e-8 };
/// let mut q = [0.0f32; 32];
/// q[0] = 1.0;
/// let f = decoder.decode(&[q]);
/// assert!(f[0] > 0.99 && f[1] < 0.01);
/// ```
#[derive(Clone, Copy, Debug)]
pub struct HostDecoder<'a> {
    /// Embedding dimension d_f.
    pub dim: usize,
    /// Projection, `QUERY_DIM × dim`, row-major.
    pub w: &'a [f32],
    /// Atoms, `K × dim`, row-major.
    pub atoms: &'a [f32],
    /// Softmax temperature τ.
    pub temperature: f32,
    /// Added to norms before dividing.
    pub eps: f32,
}

impl HostDecoder<'_> {
    /// Decodes queries to embeddings, `queries.len() × dim` row-major
    /// (zeros when there are no atoms). Memory is O(K + d_f) besides the
    /// output, so any number of queries can be decoded.
    pub fn decode(&self, queries: &[[f32; QUERY_DIM]]) -> Vec<f32> {
        let (d, eps) = (self.dim, self.eps as f64);
        let k = self.atoms.len().checked_div(d).unwrap_or(0);
        let mut out = vec![0.0f32; queries.len() * d];
        if k == 0 {
            return out;
        }
        let inv_norms: Vec<f64> = self
            .atoms
            .chunks_exact(d)
            .map(|a| 1.0 / (norm(a.iter().map(|&x| x as f64)) + eps))
            .collect();
        let (mut e, mut logits, mut f) = (vec![0.0f64; d], vec![0.0f64; k], vec![0.0f64; d]);
        for (q, out) in queries.iter().zip(out.chunks_exact_mut(d)) {
            e.fill(0.0);
            for (&qi, row) in q.iter().zip(self.w.chunks_exact(d)) {
                for (e, &wij) in e.iter_mut().zip(row) {
                    *e += qi as f64 * wij as f64;
                }
            }
            let inv_e = 1.0 / (norm(e.iter().copied()) + eps);
            let scale = inv_e / self.temperature as f64;
            for ((l, atom), inv_a) in logits
                .iter_mut()
                .zip(self.atoms.chunks_exact(d))
                .zip(&inv_norms)
            {
                let dot: f64 = e.iter().zip(atom).map(|(&x, &y)| x * y as f64).sum();
                *l = dot * inv_a * scale;
            }
            let max = logits.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let mut total = 0.0;
            for l in &mut logits {
                *l = (*l - max).exp();
                total += *l;
            }
            f.fill(0.0);
            for (&p, atom) in logits.iter().zip(self.atoms.chunks_exact(d)) {
                for (f, &a) in f.iter_mut().zip(atom) {
                    *f += p * a as f64;
                }
            }
            for (o, &v) in out.iter_mut().zip(&f) {
                *o = (v / total) as f32;
            }
        }
        out
    }
}

fn norm(v: impl Iterator<Item = f64>) -> f64 {
    v.map(|x| x * x).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentam_gpu::testing::rng;
    use latentam_reference::decoder::{forward, DecoderShape};
    use rand::Rng;

    #[test]
    fn matches_the_reference_forward_pass() {
        let mut r = rng("host_decoder");
        for (n, k, d) in [(1, 1, 3), (7, 5, 16), (33, 40, 24)] {
            let mut randn = |len: usize| -> Vec<f32> {
                (0..len).map(|_| r.random_range(-1.0f32..1.0)).collect()
            };
            let w = randn(QUERY_DIM * d);
            let atoms = randn(k * d);
            let flat = randn(n * QUERY_DIM);
            let queries: Vec<[f32; QUERY_DIM]> = flat
                .chunks_exact(QUERY_DIM)
                .map(|c| c.try_into().unwrap())
                .collect();
            let (tau, eps) = (0.07f32, 1e-6f32);
            let got = HostDecoder {
                dim: d,
                w: &w,
                atoms: &atoms,
                temperature: tau,
                eps,
            }
            .decode(&queries);
            let shape = DecoderShape {
                n,
                query_dim: QUERY_DIM,
                dim: d,
                atoms: k,
                tau: tau as f64,
                eps: eps as f64,
            };
            let want = forward(&shape, &flat, &w, &atoms).output;
            for (i, (&g, &w)) in got.iter().zip(&want).enumerate() {
                assert!(
                    (g as f64 - w).abs() <= 1e-6 * (1.0 + w.abs()),
                    "n {n} K {k} d {d}: entry {i} is {g}, reference {w}"
                );
            }
        }
    }
}
