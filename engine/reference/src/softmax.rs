//! Row softmax and its backward pass (kernels `glsl/softmax.comp`,
//! `glsl/softmax_backward.comp`).

/// y[r, :] = softmax(scale · x[r, :]) in f64, stabilised by the row max.
pub fn row_softmax(x: &[f32], rows: usize, cols: usize, scale: f64) -> Vec<f64> {
    let x: Vec<f64> = x.iter().map(|&v| v as f64).collect();
    row_softmax_f64(&x, rows, cols, scale)
}

/// [`row_softmax`] of an f64 matrix.
pub fn row_softmax_f64(x: &[f64], rows: usize, cols: usize, scale: f64) -> Vec<f64> {
    let mut y = vec![0.0; rows * cols];
    for r in 0..rows {
        let row = &x[r * cols..(r + 1) * cols];
        let m = row
            .iter()
            .map(|&v| scale * v)
            .fold(f64::NEG_INFINITY, f64::max);
        let s: f64 = row.iter().map(|&v| (scale * v - m).exp()).sum();
        for c in 0..cols {
            y[r * cols + c] = (scale * row[c] - m).exp() / s;
        }
    }
    y
}

/// Vector-Jacobian product of [`row_softmax`] (kernel
/// `glsl/softmax_backward.comp`): given a = softmax(scale · s) and
/// g = ∂L/∂a, returns ∂L/∂s = scale · a ⊙ (g − Σⱼ aⱼ gⱼ) per row.
pub fn row_softmax_vjp(a: &[f64], g: &[f64], rows: usize, cols: usize, scale: f64) -> Vec<f64> {
    let mut ds = vec![0.0; rows * cols];
    for r in 0..rows {
        let (ar, gr) = (&a[r * cols..(r + 1) * cols], &g[r * cols..(r + 1) * cols]);
        let dot: f64 = ar.iter().zip(gr).map(|(x, y)| x * y).sum();
        for c in 0..cols {
            ds[r * cols + c] = scale * ar[c] * (gr[c] - dot);
        }
    }
    ds
}
