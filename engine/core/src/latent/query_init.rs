//! Initial queries for new Gaussians from the region embeddings of the
//! keyframe that seeds them.
//!
//! The decoder reads a query `q` through `e = Wᵀq` and attends to the atoms
//! by their cosine to `e`. A query whose `Wᵀq` is the least-squares
//! approximation of the region's target `f`,
//! `q = (W Wᵀ + εI)⁻¹ W f`, decodes to about `f` before any training step:
//! with one Stage I step per keyframe, a random start would need many
//! keyframes to get there (the paper leaves the queries' initialisation
//! open). `Wᵀq` is `f` projected on the 32 rows of W, so the start is as good
//! as W is at representing the embeddings, and improves as W trains.

use crate::splat::QUERY_DIM;

/// Per-region initial queries of one keyframe: `q_r = (W Wᵀ + εI)⁻¹ W f_r`,
/// rescaled to the norm of an N(0, 1) start (√32) so that Adam's steps
/// move it as much as they move a random start. `w` is W (32 × `dim`,
/// row-major), `targets` the regions' `count × dim` embeddings. A region
/// whose target is zero or not finite, or whose projection vanishes, gets
/// `None`.
pub fn projected_queries(w: &[f32], dim: usize, targets: &[f32]) -> Vec<Option<[f32; QUERY_DIM]>> {
    if dim == 0 || w.len() != QUERY_DIM * dim {
        return vec![None; targets.len() / dim.max(1)];
    }
    // Gram matrix W Wᵀ (32 × 32) in f64, with a ridge relative to its trace
    // so that a rank-deficient W (e.g. rows that collapsed) still solves.
    let mut gram = [[0.0f64; QUERY_DIM]; QUERY_DIM];
    for i in 0..QUERY_DIM {
        for j in 0..=i {
            let s: f64 = w[i * dim..(i + 1) * dim]
                .iter()
                .zip(&w[j * dim..(j + 1) * dim])
                .map(|(&a, &b)| a as f64 * b as f64)
                .sum();
            gram[i][j] = s;
            gram[j][i] = s;
        }
    }
    let trace: f64 = (0..QUERY_DIM).map(|i| gram[i][i]).sum();
    let ridge = 1e-6 * trace / QUERY_DIM as f64 + 1e-12;
    for (i, row) in gram.iter_mut().enumerate() {
        row[i] += ridge;
    }
    let Some(chol) = cholesky(&gram) else {
        return vec![None; targets.len() / dim];
    };
    let target_norm = (QUERY_DIM as f64).sqrt();
    targets
        .chunks_exact(dim)
        .map(|f| {
            if f.iter().any(|x| !x.is_finite()) || f.iter().all(|&x| x == 0.0) {
                return None;
            }
            let mut b = [0.0f64; QUERY_DIM];
            for (i, bi) in b.iter_mut().enumerate() {
                *bi = w[i * dim..(i + 1) * dim]
                    .iter()
                    .zip(f)
                    .map(|(&a, &x)| a as f64 * x as f64)
                    .sum();
            }
            let q = solve(&chol, b);
            let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
            if !(norm > 1e-12 && norm.is_finite()) {
                return None;
            }
            Some(std::array::from_fn(|i| (q[i] / norm * target_norm) as f32))
        })
        .collect()
}

type Square = [[f64; QUERY_DIM]; QUERY_DIM];

/// Lower-triangular `L` with `L Lᵀ = a`, or `None` if `a` is not positive
/// definite.
fn cholesky(a: &Square) -> Option<Square> {
    let mut l = [[0.0f64; QUERY_DIM]; QUERY_DIM];
    for i in 0..QUERY_DIM {
        for j in 0..=i {
            let s: f64 = (0..j).map(|k| l[i][k] * l[j][k]).sum();
            if i == j {
                let d = a[i][i] - s;
                if !(d > 0.0 && d.is_finite()) {
                    return None;
                }
                l[i][i] = d.sqrt();
            } else {
                l[i][j] = (a[i][j] - s) / l[j][j];
            }
        }
    }
    Some(l)
}

/// `x` with `L Lᵀ x = b`.
fn solve(l: &Square, b: [f64; QUERY_DIM]) -> [f64; QUERY_DIM] {
    let mut y = [0.0f64; QUERY_DIM];
    for i in 0..QUERY_DIM {
        let s: f64 = (0..i).map(|k| l[i][k] * y[k]).sum();
        y[i] = (b[i] - s) / l[i][i];
    }
    let mut x = [0.0f64; QUERY_DIM];
    for i in (0..QUERY_DIM).rev() {
        let s: f64 = (i + 1..QUERY_DIM).map(|k| l[k][i] * x[k]).sum();
        x[i] = (y[i] - s) / l[i][i];
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentam_base::random::SplitMix;

    fn random(n: usize, rng: &mut SplitMix) -> Vec<f32> {
        (0..n).map(|_| rng.normal()).collect()
    }

    /// `Wᵀq` for a query.
    fn embed(w: &[f32], dim: usize, q: &[f32; QUERY_DIM]) -> Vec<f64> {
        (0..dim)
            .map(|c| {
                (0..QUERY_DIM)
                    .map(|i| w[i * dim + c] as f64 * q[i] as f64)
                    .sum()
            })
            .collect()
    }

    fn cos(a: &[f64], b: &[f32]) -> f64 {
        let dot: f64 = a.iter().zip(b).map(|(x, &y)| x * y as f64).sum();
        let na = a.iter().map(|x| x * x).sum::<f64>().sqrt();
        let nb = b.iter().map(|&y| (y as f64).powi(2)).sum::<f64>().sqrt();
        dot / (na * nb)
    }

    #[test]
    fn a_target_in_the_span_of_w_is_decoded_exactly() {
        let dim = 96;
        let mut rng = SplitMix(11);
        let w = random(QUERY_DIM * dim, &mut rng);
        // Targets Wᵀz for random z lie in W's row space.
        let z: Vec<[f32; QUERY_DIM]> = (0..5)
            .map(|_| std::array::from_fn(|_| rng.normal()))
            .collect();
        let targets: Vec<f32> = z
            .iter()
            .flat_map(|z| embed(&w, dim, z).into_iter().map(|x| x as f32))
            .collect();
        let q = projected_queries(&w, dim, &targets);
        for (r, q) in q.iter().enumerate() {
            let q = q.expect("a finite, non-zero target");
            let norm = q.iter().map(|x| x * x).sum::<f32>().sqrt();
            assert!((norm - (QUERY_DIM as f32).sqrt()).abs() < 1e-3);
            let c = cos(&embed(&w, dim, &q), &targets[r * dim..(r + 1) * dim]);
            assert!(c > 0.99999, "region {r}: cosine {c}");
        }
    }

    #[test]
    fn a_general_target_gets_its_least_squares_projection() {
        let dim = 200;
        let mut rng = SplitMix(5);
        let w = random(QUERY_DIM * dim, &mut rng);
        let f = random(dim, &mut rng);
        let q = projected_queries(&w, dim, &f)[0].unwrap();
        let e = embed(&w, dim, &q);
        // The residual f − s·Wᵀq (s the best scale) is orthogonal to every
        // row of W: the normal equations of the least-squares fit.
        let s = e.iter().zip(&f).map(|(a, &b)| a * b as f64).sum::<f64>()
            / e.iter().map(|a| a * a).sum::<f64>();
        for i in 0..QUERY_DIM {
            let r: f64 = (0..dim)
                .map(|c| (f[c] as f64 - s * e[c]) * w[i * dim + c] as f64)
                .sum();
            let scale: f64 = (0..dim).map(|c| (w[i * dim + c] as f64).abs()).sum();
            assert!(r.abs() < 1e-6 * scale, "row {i}: {r}");
        }
        // A random 32-d projection of a 200-d vector keeps about √(32/200)
        // of its direction.
        let c = cos(&e, &f);
        assert!(c > 0.25 && c < 0.6, "cosine {c}");
    }

    #[test]
    fn bad_targets_and_bad_shapes_give_none() {
        let dim = 40;
        let mut rng = SplitMix(2);
        let w = random(QUERY_DIM * dim, &mut rng);
        let mut targets = vec![0.0f32; 3 * dim];
        targets[dim..2 * dim].copy_from_slice(&random(dim, &mut rng));
        targets[2 * dim] = f32::NAN;
        let q = projected_queries(&w, dim, &targets);
        assert!(q[0].is_none() && q[1].is_some() && q[2].is_none());
        assert_eq!(projected_queries(&w[1..], dim, &targets), vec![None; 3]);
        // A zero W has no projection.
        assert_eq!(
            projected_queries(&vec![0.0; QUERY_DIM * dim], dim, &targets),
            vec![None; 3]
        );
    }
}
