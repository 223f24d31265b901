//! Dense matrix products (kernel `glsl/gemm.comp`), row-major, f64 accumulation.

/// Which operand is stored transposed (the GPU's `ops::Transpose`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transpose {
    /// A·B with A m×k, B k×n.
    None,
    /// Aᵀ·B with A stored k×m.
    A,
    /// A·Bᵀ with B stored n×k.
    B,
}

/// C = alpha·op(A)·op(B) + beta·C, all row-major and contiguous.
#[allow(clippy::too_many_arguments)]
pub fn gemm(
    t: Transpose,
    m: usize,
    n: usize,
    k: usize,
    alpha: f64,
    a: &[f32],
    b: &[f32],
    beta: f64,
    c: &mut [f32],
) {
    let at = |i: usize, p: usize| match t {
        Transpose::A => a[p * m + i],
        _ => a[i * k + p],
    } as f64;
    let bt = |p: usize, j: usize| match t {
        Transpose::B => b[j * k + p],
        _ => b[p * n + j],
    } as f64;
    for i in 0..m {
        for j in 0..n {
            let mut acc = 0.0f64;
            for p in 0..k {
                acc += at(i, p) * bt(p, j);
            }
            let old = if beta != 0.0 {
                beta * c[i * n + j] as f64
            } else {
                0.0
            };
            c[i * n + j] = (alpha * acc + old) as f32;
        }
    }
}
