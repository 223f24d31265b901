//! Per-pixel decoding for evaluation (paper Sec. IV-A: 2D embedding maps), without
//! decoding any pixel to d_f dimensions.
//!
//! The decoder (paper Eq. 5) maps a rendered query q to
//! e = Σ_k a_k D_k with a = softmax_k(⟨Ê, D̂_k⟩ / τ), Ê = qW / (‖qW‖ + ε).
//! Everything evaluation needs from e is linear in a:
//! * the logits: ⟨qW, D̂_k⟩ = q · M_k with M = W D̂ᵀ (d_s × K), and
//!   ‖qW‖² = q G qᵀ with G = W Wᵀ (d_s × d_s): d_s·K + d_s² multiply-adds
//!   a pixel instead of d_s·d_f + d_f·K;
//! * an inner product with any vector v (a class's text embedding, a
//!   region's target): ⟨e, v⟩ = a · P_v with P_v = D vᵀ (K numbers, once per
//!   vector): K multiply-adds a pixel and vector;
//! * the norm, for a cosine: ‖e‖² = aᵀ (D Dᵀ) a. The Gram matrix is K × K
//!   once; a pixel sums it over the atoms its attention actually uses
//!   (weight above [`NORM_CUTOFF`] of the largest; τ = 0.05 makes the
//!   attention sharp), |S|² multiply-adds for |S| such atoms, at most K².
//!
//! CPU reference: `latentam_reference::decoder::forward` (explicit decoding).

use crate::latent::LatentHead;
use crate::splat::QUERY_DIM;
use latentam_base::{Error, Result};
use latentam_gpu::Context;

/// Atoms whose attention weight is below this share of the pixel's largest
/// are left out of its norm: their combined share of e is under K × 1e-9.
pub const NORM_CUTOFF: f32 = 1e-9;

/// The decoder's parameters, factorised for per-pixel use on the CPU.
///
/// ```
/// use latentam_core::latent::FactorisedDecoder;
/// // 2 atoms in 3 dimensions; W maps the first query channel to atom 0.
/// let mut w = vec![0.0f32; 32 * 3];
/// w[0] = 1.0;
/// let atoms = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
/// let dec = FactorisedDecoder::new(&w, &atoms, 3, 0.05, 1e-6)?;
/// let mut q = [0.0f32; 32];
/// q[0] = 2.0;
/// let mut a = vec![0.0; 2];
/// dec.attention(&q, &mut a);
/// assert!(a[0] > 0.999);
/// let p = dec.project(&[1.0, 0.0, 0.0]); // ⟨e, (1, 0, 0)⟩ = a · p
/// assert!((FactorisedDecoder::dot(&a, &p) - 1.0).abs() < 1e-3);
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct FactorisedDecoder {
    atoms: usize,
    dim: usize,
    inv_tau: f32,
    eps: f32,
    /// W D̂ᵀ, QUERY_DIM × K.
    m: Vec<f32>,
    /// W Wᵀ, QUERY_DIM × QUERY_DIM.
    g: Vec<f32>,
    /// D, K × d_f.
    d: Vec<f32>,
    /// D Dᵀ, K × K.
    gram: Vec<f32>,
}

impl FactorisedDecoder {
    /// From W (`QUERY_DIM` × d_f, row-major), the atoms D (K × d_f), the
    /// softmax temperature τ and the norm's ε.
    pub fn new(w: &[f32], atoms: &[f32], dim: usize, temperature: f32, eps: f32) -> Result<Self> {
        if dim == 0
            || w.len() != QUERY_DIM * dim
            || atoms.is_empty()
            || !atoms.len().is_multiple_of(dim)
        {
            return Err(Error::bad_input(
                "pixel decoder sizes",
                format!(
                    "{} W values and {} atom values for {dim}-d embeddings",
                    w.len(),
                    atoms.len()
                ),
            ));
        }
        if !(temperature > 0.0 && temperature.is_finite()) || eps < 0.0 {
            return Err(Error::bad_input(
                "decoder temperature and eps",
                format!(
                    "temperature {temperature} must be finite and positive, eps {eps} non-negative"
                ),
            ));
        }
        let k = atoms.len() / dim;
        let dot = |a: &[f32], b: &[f32]| -> f64 {
            a.iter().zip(b).map(|(&x, &y)| x as f64 * y as f64).sum()
        };
        let d_hat: Vec<Vec<f32>> = atoms
            .chunks_exact(dim)
            .map(|row| {
                let n = dot(row, row).sqrt() as f32 + eps;
                row.iter().map(|&x| x / n).collect()
            })
            .collect();
        let w_rows: Vec<&[f32]> = w.chunks_exact(dim).collect();
        let mut m = vec![0.0f32; QUERY_DIM * k];
        for (i, wi) in w_rows.iter().enumerate() {
            for (j, dj) in d_hat.iter().enumerate() {
                m[i * k + j] = dot(wi, dj) as f32;
            }
        }
        let mut g = vec![0.0f32; QUERY_DIM * QUERY_DIM];
        for i in 0..QUERY_DIM {
            for j in 0..QUERY_DIM {
                g[i * QUERY_DIM + j] = dot(w_rows[i], w_rows[j]) as f32;
            }
        }
        let rows: Vec<&[f32]> = atoms.chunks_exact(dim).collect();
        let mut gram = vec![0.0f32; k * k];
        for i in 0..k {
            for j in i..k {
                let v = dot(rows[i], rows[j]) as f32;
                gram[i * k + j] = v;
                gram[j * k + i] = v;
            }
        }
        Ok(Self {
            atoms: k,
            dim,
            inv_tau: 1.0 / temperature,
            eps,
            m,
            g,
            d: atoms.to_vec(),
            gram,
        })
    }

    /// The head's current W and atoms (downloaded).
    pub fn from_head(ctx: &Context, head: &LatentHead) -> Result<Self> {
        let cfg = head.config();
        let k = head.atom_count() as usize;
        if k == 0 {
            return Err(Error::NoEmbeddings);
        }
        let dim = cfg.dim as usize;
        let w = ctx.download::<f32>(head.w())?;
        let atoms = ctx.download::<f32>(head.atoms())?;
        Self::new(
            &w[..QUERY_DIM * dim],
            &atoms[..k * dim],
            dim,
            cfg.temperature,
            head.decoder().config().eps,
        )
    }

    /// Atoms K.
    pub fn atoms(&self) -> usize {
        self.atoms
    }

    /// Embedding dimension d_f.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// The attention weights `a` (K) of query `q`.
    pub fn attention(&self, q: &[f32; QUERY_DIM], a: &mut [f32]) {
        let k = self.atoms;
        let mut norm2 = 0.0f32;
        for i in 0..QUERY_DIM {
            let gi = &self.g[i * QUERY_DIM..(i + 1) * QUERY_DIM];
            norm2 += q[i] * gi.iter().zip(q).map(|(g, x)| g * x).sum::<f32>();
        }
        let scale = self.inv_tau / (norm2.max(0.0).sqrt() + self.eps);
        a[..k].fill(0.0);
        for (i, &qi) in q.iter().enumerate() {
            if qi != 0.0 {
                let mi = &self.m[i * k..(i + 1) * k];
                for (aj, &mj) in a[..k].iter_mut().zip(mi) {
                    *aj += qi * mj;
                }
            }
        }
        let top = a[..k].iter().fold(f32::NEG_INFINITY, |t, &x| t.max(x));
        let mut sum = 0.0f32;
        for x in a[..k].iter_mut() {
            *x = ((*x - top) * scale).exp();
            sum += *x;
        }
        for x in a[..k].iter_mut() {
            *x /= sum;
        }
    }

    /// P_v = D vᵀ for each of the `vectors` (m × d_f): m rows of K, so that
    /// ⟨e, v⟩ = [`FactorisedDecoder::dot`]`(a, P_v)`.
    pub fn project(&self, vectors: &[f32]) -> Vec<f32> {
        let k = self.atoms;
        let mut p = Vec::with_capacity(vectors.len() / self.dim.max(1) * k);
        for v in vectors.chunks_exact(self.dim) {
            for row in self.d.chunks_exact(self.dim) {
                p.push(
                    row.iter()
                        .zip(v)
                        .map(|(&x, &y)| x as f64 * y as f64)
                        .sum::<f64>() as f32,
                );
            }
        }
        p
    }

    /// a · p.
    pub fn dot(a: &[f32], p: &[f32]) -> f32 {
        a.iter().zip(p).map(|(x, y)| x * y).sum()
    }

    /// ‖e‖ for attention `a`: √(aᵀ D Dᵀ a) over the atoms weighing at least
    /// [`NORM_CUTOFF`] of the largest weight. `used` is scratch space.
    pub fn norm(&self, a: &[f32], used: &mut Vec<usize>) -> f32 {
        let k = self.atoms;
        let top = a[..k].iter().fold(0.0f32, |t, &x| t.max(x));
        used.clear();
        used.extend((0..k).filter(|&j| a[j] >= top * NORM_CUTOFF));
        let mut s = 0.0f32;
        for &i in used.iter() {
            let row = &self.gram[i * k..(i + 1) * k];
            let inner: f32 = used.iter().map(|&j| row[j] * a[j]).sum();
            s += a[i] * inner;
        }
        s.max(0.0).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use latentam_gpu::testing::rng;
    use latentam_reference::decoder::{forward, DecoderShape};

    #[test]
    fn factorised_decoding_equals_explicit_decoding() {
        let mut r = rng("factorised_decoding");
        for (dim, k, tau) in [(24usize, 7usize, 0.05f32), (40, 13, 0.2), (16, 1, 0.05)] {
            let w: Vec<f32> = (0..QUERY_DIM * dim)
                .map(|_| r.random_range(-0.5..0.5))
                .collect();
            let d: Vec<f32> = (0..k * dim).map(|_| r.random_range(-1.0..1.0)).collect();
            let n = 9;
            let q: Vec<f32> = (0..n * QUERY_DIM)
                .map(|_| r.random_range(-1.0..1.0))
                .collect();
            let texts: Vec<f32> = (0..3 * dim).map(|_| r.random_range(-1.0..1.0)).collect();
            let shape = DecoderShape {
                n,
                query_dim: QUERY_DIM,
                dim,
                atoms: k,
                tau: tau as f64,
                eps: 1e-6,
            };
            let want = forward(&shape, &q, &w, &d);
            let dec = FactorisedDecoder::new(&w, &d, dim, tau, 1e-6).unwrap();
            let p = dec.project(&texts);
            let mut a = vec![0.0; k];
            let mut used = Vec::new();
            for i in 0..n {
                let qi: [f32; QUERY_DIM] =
                    q[i * QUERY_DIM..(i + 1) * QUERY_DIM].try_into().unwrap();
                dec.attention(&qi, &mut a);
                for (j, &aj) in a.iter().enumerate() {
                    let e = (aj as f64 - want.attention[i * k + j]).abs();
                    assert!(
                        e < 1e-5,
                        "attention {i},{j}: {} vs {}",
                        aj,
                        want.attention[i * k + j]
                    );
                }
                let e = &want.output[i * dim..(i + 1) * dim];
                let norm = e.iter().map(|x| x * x).sum::<f64>().sqrt();
                let got = dec.norm(&a, &mut used) as f64;
                assert!(
                    (got - norm).abs() < 1e-4 * norm.max(1.0),
                    "norm {got} vs {norm}"
                );
                for (c, t) in texts.chunks_exact(dim).enumerate() {
                    let want_dot: f64 = e.iter().zip(t).map(|(x, &y)| x * y as f64).sum();
                    let got = FactorisedDecoder::dot(&a, &p[c * k..(c + 1) * k]) as f64;
                    assert!(
                        (got - want_dot).abs() < 1e-4 * want_dot.abs().max(1.0),
                        "⟨e, t{c}⟩"
                    );
                }
            }
        }
    }

    #[test]
    fn bad_shapes_are_errors() {
        assert!(FactorisedDecoder::new(&[0.0; 10], &[1.0; 4], 2, 0.05, 1e-6).is_err());
        assert!(FactorisedDecoder::new(&[0.0; 64], &[1.0; 3], 2, 0.05, 1e-6).is_err());
        assert!(FactorisedDecoder::new(&[0.0; 64], &[1.0; 4], 2, 0.0, 1e-6).is_err());
        assert!(FactorisedDecoder::new(&[0.0; 64], &[], 2, 0.05, 1e-6).is_err());
    }
}
