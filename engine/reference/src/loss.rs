//! Mapping losses and their gradients (paper Eqs. 6–8; kernels in
//! `engine/core/src/loss/`), in f64. SSIM has its own module,
//! [`crate::ssim`].
//!
//! `L_f = λ_cos (1 − cos(F̂, F)) + λ_2 ‖F̂ − F‖² + λ_D Σ_j ReLU(‖D⁰_j − D_j‖ − δ)` (Eq. 6),
//! `L_rgb = λ_I1 ‖Î − I‖₁ + λ_I2 L_SSIM(Î, I)` (Eq. 7), `L_d = ‖Ẑ − Z‖₁` (Eq. 8).

/// Per-row feature loss between decoded embeddings `pred` and targets
/// `target` (rows × cols), weighted per row:
///
/// ```text
/// loss_m = w_m · (λ_cos · (1 − cos(p_m, t_m)) + λ_2 · ‖p_m − t_m‖² / cols)
/// cos(p, t) = p·t / (max(‖p‖, ε) · max(‖t‖, ε))
/// ```
///
/// Returns (loss per row, ∂Σloss/∂pred).
pub fn feature_loss(
    pred: &[f32],
    target: &[f32],
    weights: &[f32],
    cols: usize,
    lambda_cos: f64,
    lambda_l2: f64,
    eps: f64,
) -> (Vec<f64>, Vec<f64>) {
    let rows = weights.len();
    let mut loss = vec![0.0; rows];
    let mut grad = vec![0.0; rows * cols];
    for m in 0..rows {
        let p: Vec<f64> = pred[m * cols..(m + 1) * cols]
            .iter()
            .map(|&v| v as f64)
            .collect();
        let t: Vec<f64> = target[m * cols..(m + 1) * cols]
            .iter()
            .map(|&v| v as f64)
            .collect();
        let w = weights[m] as f64;
        let dot: f64 = p.iter().zip(&t).map(|(a, b)| a * b).sum();
        let a = p.iter().map(|v| v * v).sum::<f64>().sqrt();
        let b = t.iter().map(|v| v * v).sum::<f64>().sqrt();
        let (ac, bc) = (a.max(eps), b.max(eps));
        let cos = dot / (ac * bc);
        let se: f64 = p.iter().zip(&t).map(|(x, y)| (x - y) * (x - y)).sum();
        loss[m] = w * (lambda_cos * (1.0 - cos) + lambda_l2 * se / cols as f64);
        // Below ε the clamped norm is constant, so only the first term moves.
        let radial = if a > eps { cos / (a * a) } else { 0.0 };
        for j in 0..cols {
            let dcos = t[j] / (ac * bc) - radial * p[j];
            grad[m * cols + j] =
                w * (-lambda_cos * dcos + 2.0 * lambda_l2 * (p[j] - t[j]) / cols as f64);
        }
    }
    (loss, grad)
}

/// Trust-region penalty on the dictionary:
/// `loss_k = λ · max(0, ‖D_k − D⁰_k‖ − radius)`. Returns (loss per atom,
/// ∂Σloss/∂D).
pub fn trust_region(
    atoms: &[f32],
    anchor: &[f32],
    cols: usize,
    lambda: f64,
    radius: f64,
) -> (Vec<f64>, Vec<f64>) {
    let rows = atoms.len() / cols.max(1);
    let mut loss = vec![0.0; rows];
    let mut grad = vec![0.0; atoms.len()];
    for k in 0..rows {
        let diff: Vec<f64> = (0..cols)
            .map(|j| atoms[k * cols + j] as f64 - anchor[k * cols + j] as f64)
            .collect();
        let norm = diff.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm > radius {
            loss[k] = lambda * (norm - radius);
            for j in 0..cols {
                grad[k * cols + j] = lambda * diff[j] / norm;
            }
        }
    }
    (loss, grad)
}

/// Photometric and depth L1 of one view, per-element weights folded in:
/// `l1 = w_rgb · Σ_p Σ_c |r − t|` and `depth = w_depth · Σ_{valid p} |r_z − t_z|`
/// where a target depth is valid when positive and finite. Pixels are
/// (R, G, B, depth). Returns (l1, depth, ∂(l1 + depth)/∂rendered).
pub fn image_l1_depth(
    rendered: &[[f32; 4]],
    target: &[[f32; 4]],
    w_rgb: f64,
    w_depth: f64,
) -> (f64, f64, Vec<[f64; 4]>) {
    let (mut l1, mut depth) = (0.0, 0.0);
    let mut grad = vec![[0.0; 4]; rendered.len()];
    for (p, (r, t)) in rendered.iter().zip(target).enumerate() {
        for c in 0..3 {
            let e = r[c] as f64 - t[c] as f64;
            l1 += w_rgb * e.abs();
            grad[p][c] = w_rgb * sign(e);
        }
        if t[3] > 0.0 && t[3].is_finite() {
            let e = r[3] as f64 - t[3] as f64;
            depth += w_depth * e.abs();
            grad[p][3] = w_depth * sign(e);
        }
    }
    (l1, depth, grad)
}

/// Sign with sign(0) = 0 (the subgradient L1 kernels use).
fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::*;

    /// Central differences of Σ loss with respect to each input entry.
    fn finite_differences(x: &[f32], f: impl Fn(&[f32]) -> f64) -> Vec<f64> {
        let h = 1e-3f32;
        (0..x.len())
            .map(|i| {
                let (mut a, mut b) = (x.to_vec(), x.to_vec());
                a[i] += h;
                b[i] -= h;
                (f(&a) - f(&b)) / (a[i] as f64 - b[i] as f64)
            })
            .collect()
    }

    #[test]
    fn feature_loss_gradient_matches_central_differences() {
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (rows, cols) = (4, 7);
        let mut pred: Vec<f32> = (0..rows * cols)
            .map(|_| r.random_range(-1.0..1.0))
            .collect();
        let target: Vec<f32> = (0..rows * cols)
            .map(|_| r.random_range(-1.0..1.0))
            .collect();
        // A row whose prediction is below ε: the clamped branch.
        for v in &mut pred[cols..2 * cols] {
            *v *= 1e-9;
        }
        let weights = [0.5f32, 1.0, 2.0, 0.0];
        let total = |p: &[f32]| -> f64 {
            feature_loss(p, &target, &weights, cols, 0.7, 0.3, 1e-8)
                .0
                .iter()
                .sum()
        };
        let (_, grad) = feature_loss(&pred, &target, &weights, cols, 0.7, 0.3, 1e-8);
        let fd = finite_differences(&pred, total);
        for i in 0..grad.len() {
            if (cols..2 * cols).contains(&i) {
                continue; // a step of 1e-3 leaves the clamped branch
            }
            assert!(
                (grad[i] - fd[i]).abs() <= 1e-5 * (1.0 + fd[i].abs()),
                "pred[{i}]: analytic {} vs {}",
                grad[i],
                fd[i]
            );
        }
    }

    #[test]
    fn trust_region_gradient_matches_central_differences() {
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let cols = 5;
        let anchor: Vec<f32> = (0..3 * cols).map(|_| r.random_range(-1.0..1.0)).collect();
        // Atom 0 inside the radius, atoms 1 and 2 outside.
        let atoms: Vec<f32> = anchor
            .iter()
            .enumerate()
            .map(|(i, &a)| {
                a + if i < cols {
                    0.01
                } else {
                    r.random_range(-0.5..0.5)
                }
            })
            .collect();
        let total = |d: &[f32]| -> f64 { trust_region(d, &anchor, cols, 0.2, 0.1).0.iter().sum() };
        let (loss, grad) = trust_region(&atoms, &anchor, cols, 0.2, 0.1);
        assert_eq!(loss[0], 0.0);
        assert!(loss[1] > 0.0 && loss[2] > 0.0);
        let fd = finite_differences(&atoms, total);
        for i in 0..grad.len() {
            assert!(
                (grad[i] - fd[i]).abs() <= 1e-5,
                "D[{i}]: {} vs {}",
                grad[i],
                fd[i]
            );
        }
    }
}
