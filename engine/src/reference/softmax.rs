//! Row softmax (kernel `glsl/softmax.comp`).

/// y[r, :] = softmax(scale · x[r, :]) in f64, stabilised by the row max.
pub fn row_softmax(x: &[f32], rows: usize, cols: usize, scale: f64) -> Vec<f64> {
    let mut y = vec![0.0; rows * cols];
    for r in 0..rows {
        let row = &x[r * cols..(r + 1) * cols];
        let m = row
            .iter()
            .map(|&v| scale * v as f64)
            .fold(f64::NEG_INFINITY, f64::max);
        let s: f64 = row.iter().map(|&v| (scale * v as f64 - m).exp()).sum();
        for c in 0..cols {
            y[r * cols + c] = (scale * row[c] as f64 - m).exp() / s;
        }
    }
    y
}
