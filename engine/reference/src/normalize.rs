//! Row normalisation with an epsilon on the norm (kernels
//! `glsl/normalize_rows.comp`, `glsl/normalize_rows_backward.comp`), as the
//! attention decoder uses it.

/// Row-wise y = x / (‖x‖ + ε); returns (y, ‖x‖).
pub fn normalize_rows(x: &[f64], rows: usize, cols: usize, eps: f64) -> (Vec<f64>, Vec<f64>) {
    let mut y = vec![0.0; rows * cols];
    let mut norms = vec![0.0; rows];
    for r in 0..rows {
        let row = &x[r * cols..(r + 1) * cols];
        let norm = row.iter().map(|v| v * v).sum::<f64>().sqrt();
        norms[r] = norm;
        for c in 0..cols {
            y[r * cols + c] = row[c] / (norm + eps);
        }
    }
    (y, norms)
}

/// Vector-Jacobian product of [`normalize_rows`]: given y, ‖x‖ and g = ∂L/∂y,
/// returns ∂L/∂x = g/(r+ε) − y (y·g)/r per row (the second term vanishes as
/// r → 0, and is taken as 0 at r = 0).
pub fn normalize_rows_vjp(y: &[f64], norms: &[f64], g: &[f64], cols: usize, eps: f64) -> Vec<f64> {
    let mut dx = vec![0.0; y.len()];
    for (r, &norm) in norms.iter().enumerate() {
        let yr = &y[r * cols..(r + 1) * cols];
        let gr = &g[r * cols..(r + 1) * cols];
        let yg: f64 = yr.iter().zip(gr).map(|(a, b)| a * b).sum();
        let k = if norm > 0.0 { yg / norm } else { 0.0 };
        for c in 0..cols {
            dx[r * cols + c] = gr[c] / (norm + eps) - yr[c] * k;
        }
    }
    dx
}
