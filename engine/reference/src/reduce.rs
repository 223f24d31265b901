//! Sum and max reductions (kernel `glsl/reduce.comp`).

/// Sum in f64, the exact-enough value the f32 GPU tree is compared with.
pub fn sum(data: &[f32]) -> f64 {
    data.iter().map(|&x| x as f64).sum()
}

/// Maximum; `-inf` for an empty slice (the kernel's identity).
pub fn max(data: &[f32]) -> f32 {
    data.iter().cloned().fold(f32::NEG_INFINITY, f32::max)
}
