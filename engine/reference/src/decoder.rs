//! The dictionary attention decoder (paper Sec. III-B, Eq. 5; kernels in
//! `engine/core/src/latent/decoder.rs`), in f64.
//!
//! Region queries `Q` (n × d_s) are projected by `W` (d_s × d_f) to `E = QW`;
//! each row is compared by cosine similarity with the dictionary atoms `D`
//! (K × d_f); a softmax over the atoms at temperature τ gives the attention
//! `A`; the decoded embedding is `F̂ = A·D` with the *un-normalised* atoms.
//!
//! ```text
//! E = Q W ;  Ê_i = E_i / (‖E_i‖ + ε) ;  D̂_k = D_k / (‖D_k‖ + ε)
//! S = Ê D̂ᵀ / τ ;  A = softmax_row(S) ;  F̂ = A D
//! ```

use super::normalize::{normalize_rows, normalize_rows_vjp};
use super::softmax::{row_softmax_f64, row_softmax_vjp};

/// Shapes and constants of one decode.
///
/// ```
/// use latentam_reference::decoder::{forward, DecoderShape};
///
/// // Two regions with 2-d queries, 3-d embeddings, a dictionary of two atoms.
/// let s = DecoderShape { n: 2, query_dim: 2, dim: 3, atoms: 2, tau: 0.1, eps: 1e-12 };
/// let w = [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0]; // d_s × d_f
/// let d = [2.0f32, 0.0, 0.0, 0.0, 3.0, 0.0]; // K × d_f
/// let fwd = forward(&s, &[1.0, 0.0, 0.0, 1.0], &w, &d);
/// assert_eq!(fwd.output.len(), s.n * s.dim);
/// ```
#[derive(Clone, Copy, Debug)]
pub struct DecoderShape {
    /// Rows (regions).
    pub n: usize,
    /// Query dimension d_s.
    pub query_dim: usize,
    /// Embedding dimension d_f.
    pub dim: usize,
    /// Atoms K.
    pub atoms: usize,
    /// Softmax temperature τ.
    pub tau: f64,
    /// Added to every norm before dividing.
    pub eps: f64,
}

/// Everything the forward pass computes (the backward pass reuses it).
///
/// ```
/// use latentam_reference::decoder::{forward, DecoderShape};
///
/// let s = DecoderShape { n: 2, query_dim: 2, dim: 3, atoms: 2, tau: 0.1, eps: 1e-12 };
/// let (w, d) = ([1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0], [2.0f32, 0.0, 0.0, 0.0, 3.0, 0.0]);
/// let fwd = forward(&s, &[1.0, 0.0, 0.0, 1.0], &w, &d);
/// for row in fwd.attention.chunks(s.atoms) {
///     assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12); // a softmax over atoms
/// }
/// // Region 0 points at atom 0 and decodes to it, unnormalised: ≈ (2, 0, 0).
/// assert!(fwd.attention[0] > 0.99 && (fwd.output[0] - 2.0).abs() < 1e-3);
/// ```
#[derive(Clone, Debug)]
pub struct DecoderForward {
    /// E = QW, n × d_f.
    pub e: Vec<f64>,
    /// ‖E_i‖, n.
    pub e_norm: Vec<f64>,
    /// Ê, n × d_f.
    pub e_hat: Vec<f64>,
    /// ‖D_k‖, K.
    pub d_norm: Vec<f64>,
    /// D̂, K × d_f.
    pub d_hat: Vec<f64>,
    /// Attention A, n × K.
    pub attention: Vec<f64>,
    /// F̂ = A D, n × d_f.
    pub output: Vec<f64>,
}

/// Gradients of the decoder's inputs.
///
/// ```
/// use latentam_reference::decoder::{backward, forward, DecoderShape};
///
/// let s = DecoderShape { n: 2, query_dim: 2, dim: 3, atoms: 2, tau: 0.5, eps: 1e-12 };
/// let (q, d) = ([1.0f32, 0.2, 0.3, 1.0], [2.0f32, 0.0, 0.5, 0.0, 3.0, 0.0]);
/// let w = [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0];
/// let loss = |w: &[f32]| forward(&s, &q, w, &d).output.iter().sum::<f64>();
/// // L = Σ F̂, so the upstream gradient is all ones.
/// let grads = backward(&s, &q, &w, &d, &forward(&s, &q, &w, &d), &[1.0; 6]);
/// let (mut up, mut down) = (w, w);
/// up[1] += 1e-3;
/// down[1] -= 1e-3;
/// assert!(((loss(&up) - loss(&down)) / 2e-3 - grads.w[1]).abs() < 1e-3);
/// ```
#[derive(Clone, Debug)]
pub struct DecoderGrads {
    /// ∂L/∂Q, n × d_s.
    pub queries: Vec<f64>,
    /// ∂L/∂W, d_s × d_f.
    pub w: Vec<f64>,
    /// ∂L/∂D, K × d_f.
    pub d: Vec<f64>,
}

/// C (m×n) = A (m×k) · B (k×n), all row-major.
fn matmul(a: &[f64], b: &[f64], m: usize, k: usize, n: usize) -> Vec<f64> {
    let mut c = vec![0.0; m * n];
    for i in 0..m {
        for p in 0..k {
            let aip = a[i * k + p];
            for j in 0..n {
                c[i * n + j] += aip * b[p * n + j];
            }
        }
    }
    c
}

/// Transpose of a rows × cols matrix.
fn transpose(a: &[f64], rows: usize, cols: usize) -> Vec<f64> {
    let mut t = vec![0.0; rows * cols];
    for i in 0..rows {
        for j in 0..cols {
            t[j * rows + i] = a[i * cols + j];
        }
    }
    t
}

/// The forward pass. `q` is n × d_s, `w` d_s × d_f, `d` K × d_f.
pub fn forward(s: &DecoderShape, q: &[f32], w: &[f32], d: &[f32]) -> DecoderForward {
    let q: Vec<f64> = q.iter().map(|&v| v as f64).collect();
    let w: Vec<f64> = w.iter().map(|&v| v as f64).collect();
    let d: Vec<f64> = d.iter().map(|&v| v as f64).collect();
    let e = matmul(&q, &w, s.n, s.query_dim, s.dim);
    let (e_hat, e_norm) = normalize_rows(&e, s.n, s.dim, s.eps);
    let (d_hat, d_norm) = normalize_rows(&d, s.atoms, s.dim, s.eps);
    let logits = matmul(
        &e_hat,
        &transpose(&d_hat, s.atoms, s.dim),
        s.n,
        s.dim,
        s.atoms,
    );
    let attention = row_softmax_f64(&logits, s.n, s.atoms, 1.0 / s.tau);
    let output = matmul(&attention, &d, s.n, s.atoms, s.dim);
    DecoderForward {
        e,
        e_norm,
        e_hat,
        d_norm,
        d_hat,
        attention,
        output,
    }
}

/// The backward pass for ∂L/∂F̂ = `g` (n × d_f).
pub fn backward(
    s: &DecoderShape,
    q: &[f32],
    w: &[f32],
    d: &[f32],
    fwd: &DecoderForward,
    g: &[f64],
) -> DecoderGrads {
    let q: Vec<f64> = q.iter().map(|&v| v as f64).collect();
    let w: Vec<f64> = w.iter().map(|&v| v as f64).collect();
    let d: Vec<f64> = d.iter().map(|&v| v as f64).collect();
    let (n, k, df, ds) = (s.n, s.atoms, s.dim, s.query_dim);
    // Direct path of F̂ = A D.
    let d_attention = matmul(g, &transpose(&d, k, df), n, df, k);
    let mut grad_d = matmul(&transpose(&fwd.attention, n, k), g, k, n, df);
    // Softmax, with the 1/τ of the logits.
    let d_logits = row_softmax_vjp(&fwd.attention, &d_attention, n, k, 1.0 / s.tau);
    let d_e_hat = matmul(&d_logits, &fwd.d_hat, n, k, df);
    let d_d_hat = matmul(&transpose(&d_logits, n, k), &fwd.e_hat, k, n, df);
    let via_norm = normalize_rows_vjp(&fwd.d_hat, &fwd.d_norm, &d_d_hat, df, s.eps);
    for (a, b) in grad_d.iter_mut().zip(&via_norm) {
        *a += b;
    }
    let d_e = normalize_rows_vjp(&fwd.e_hat, &fwd.e_norm, &d_e_hat, df, s.eps);
    let grad_w = matmul(&transpose(&q, n, ds), &d_e, ds, n, df);
    let grad_q = matmul(&d_e, &transpose(&w, ds, df), n, df, ds);
    DecoderGrads {
        queries: grad_q,
        w: grad_w,
        d: grad_d,
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::*;

    /// L = Σ F̂ ⊙ R for a fixed random R, so ∂L/∂F̂ = R.
    fn loss(s: &DecoderShape, q: &[f32], w: &[f32], d: &[f32], r: &[f64]) -> f64 {
        let f = forward(s, q, w, d);
        f.output.iter().zip(r).map(|(a, b)| a * b).sum()
    }

    #[test]
    fn backward_matches_central_differences() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let s = DecoderShape {
            n: 3,
            query_dim: 4,
            dim: 6,
            atoms: 5,
            tau: 0.3,
            eps: 1e-6,
        };
        let q: Vec<f32> = (0..s.n * s.query_dim)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let w: Vec<f32> = (0..s.query_dim * s.dim)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let d: Vec<f32> = (0..s.atoms * s.dim)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let r: Vec<f64> = (0..s.n * s.dim)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let fwd = forward(&s, &q, &w, &d);
        let g = backward(&s, &q, &w, &d, &fwd, &r);
        // f32 inputs limit the step; 1e-3 keeps truncation and rounding small.
        let h = 1e-3f32;
        let inputs = [q, w, d];
        let loss_at = |x: &[Vec<f32>; 3]| loss(&s, &x[0], &x[1], &x[2], &r);
        for (which, name, analytic) in [(0, "Q", &g.queries), (1, "W", &g.w), (2, "D", &g.d)] {
            for i in 0..analytic.len() {
                let (mut plus, mut minus) = (inputs.clone(), inputs.clone());
                plus[which][i] += h;
                minus[which][i] -= h;
                // The step actually taken after rounding to f32.
                let step = plus[which][i] as f64 - minus[which][i] as f64;
                let fd = (loss_at(&plus) - loss_at(&minus)) / step;
                assert!(
                    (fd - analytic[i]).abs() <= 1e-4 * (1.0 + fd.abs()),
                    "{name}[{i}]: analytic {} vs finite difference {fd}",
                    analytic[i]
                );
            }
        }
    }
}
