//! Scatter-add of floats (kernels `atomic_add_f32` and `atomic_add_f32_cas`).

/// `acc[targets[i]] += values[i]` for every i, in f64.
pub fn scatter_add(values: &[f32], targets: &[u32], bins: usize) -> Vec<f64> {
    let mut acc = vec![0.0f64; bins];
    for (&v, &t) in values.iter().zip(targets) {
        acc[t as usize] += v as f64;
    }
    acc
}
