//! Single-precision matrix products (kernels `gemm_nn`, `gemm_tn`, `gemm_nt`
//! in `glsl/gemm.comp`; CPU reference [`crate::reference::gemm`]).

use latentam_shaders::{push, GEMM_NN, GEMM_NT, GEMM_TN};

use crate::error::Result;
use crate::gpu::{Buffer, Recorder};
pub use crate::reference::gemm::Transpose;

/// Rows and columns of C computed per workgroup.
pub const GEMM_TILE: u32 = 64;

/// Shape and scaling of one product `C = alpha·op(A)·op(B) + beta·C`
/// (row-major, contiguous; op(A) is m×k, op(B) is k×n).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gemm {
    /// Which operand is transposed.
    pub transpose: Transpose,
    /// Rows of C.
    pub m: u32,
    /// Columns of C.
    pub n: u32,
    /// Inner dimension.
    pub k: u32,
    /// Scale of the product.
    pub alpha: f32,
    /// Scale of the old C (0 = overwrite without reading C).
    pub beta: f32,
}

impl Gemm {
    /// Flops of one product (2·m·n·k).
    pub fn flops(&self) -> f64 {
        2.0 * self.m as f64 * self.n as f64 * self.k as f64
    }

    /// Records the product.
    pub fn record<'a>(
        &self,
        rec: &mut Recorder<'a>,
        a: &'a Buffer,
        b: &'a Buffer,
        c: &'a Buffer,
    ) -> Result<()> {
        let (m, n, k) = (self.m as u64, self.n as u64, self.k as u64);
        for (buf, elems, what) in [(a, m * k, "A"), (b, k * n, "B"), (c, m * n, "C")] {
            buf.ensure_bytes(elems * 4, &format!("GEMM {m}x{n}x{k} operand {what}"))?;
        }
        let (lda, ldb) = match self.transpose {
            Transpose::None => (self.k, self.n),
            Transpose::A => (self.m, self.n),
            Transpose::B => (self.k, self.k),
        };
        let p = push::GemmNn {
            m: self.m,
            n: self.n,
            k: self.k,
            lda,
            ldb,
            ldc: self.n,
            alpha: self.alpha,
            beta: self.beta,
        };
        let groups = [self.n.div_ceil(GEMM_TILE), self.m.div_ceil(GEMM_TILE), 1];
        match self.transpose {
            Transpose::None => rec.dispatch(&GEMM_NN, groups, &[a, b, c], &p),
            Transpose::A => rec.dispatch(&GEMM_TN, groups, &[a, b, c], bytemuck::cast_ref(&p)),
            Transpose::B => rec.dispatch(&GEMM_NT, groups, &[a, b, c], bytemuck::cast_ref(&p)),
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use crate::gpu::testing::{rng, with_context};
    use crate::reference::gemm::gemm;

    #[test]
    fn gemm_variants_match_reference_on_random_shapes() {
        let mut r = rng("gemm_variants_match_reference_on_random_shapes");
        with_context(|ctx| {
            let mut shapes = vec![
                (1u32, 1u32, 1u32),
                (64, 64, 16),
                (65, 63, 17),
                (3, 130, 200),
            ];
            for _ in 0..3 {
                shapes.push((
                    r.random_range(1..150),
                    r.random_range(1..150),
                    r.random_range(1..300),
                ));
            }
            for (m, n, k) in shapes {
                for t in [Transpose::None, Transpose::A, Transpose::B] {
                    for (alpha, beta) in [(1.0f32, 0.0f32), (0.5, -2.0)] {
                        let a: Vec<f32> = (0..m * k).map(|_| r.random_range(-1.0..1.0)).collect();
                        let b: Vec<f32> = (0..k * n).map(|_| r.random_range(-1.0..1.0)).collect();
                        let mut c: Vec<f32> =
                            (0..m * n).map(|_| r.random_range(-1.0..1.0)).collect();
                        let ab = ctx.upload_new("test/a", &a).unwrap();
                        let bb = ctx.upload_new("test/b", &b).unwrap();
                        let cb = Buffer::device(ctx, "test/c", (m * n * 4) as u64).unwrap();
                        let g = Gemm {
                            transpose: t,
                            m,
                            n,
                            k,
                            alpha,
                            beta,
                        };
                        let mut rec = ctx.recorder().unwrap();
                        if beta == 0.0 {
                            rec.fill_u32(&cb, 0x7fc0_0000); // NaN: must not be read
                        } else {
                            rec.upload(&cb, 0, &c).unwrap();
                        }
                        g.record(&mut rec, &ab, &bb, &cb).unwrap();
                        rec.submit().unwrap().wait().unwrap();
                        let got = ctx.download::<f32>(&cb).unwrap();
                        gemm(
                            t,
                            m as usize,
                            n as usize,
                            k as usize,
                            alpha as f64,
                            &a,
                            &b,
                            beta as f64,
                            &mut c,
                        );
                        // |error| ≤ k·eps·Σ|a||b| ≤ k·eps·k for entries in [-1, 1].
                        let tol = 1e-6 * (k as f32) * 4.0 + 1e-5;
                        for i in 0..(m * n) as usize {
                            assert!(
                                (got[i] - c[i]).abs() <= tol,
                                "{t:?} {m}x{n}x{k} alpha={alpha} beta={beta}: C[{i}] = {} want {}",
                                got[i],
                                c[i]
                            );
                        }
                    }
                }
            }
        });
    }

    #[test]
    fn gemm_rejects_small_buffers() {
        with_context(|ctx| {
            let a = Buffer::device(ctx, "test/a", 16).unwrap();
            let g = Gemm {
                transpose: Transpose::None,
                m: 4,
                n: 4,
                k: 4,
                alpha: 1.0,
                beta: 0.0,
            };
            let mut rec = ctx.recorder().unwrap();
            assert!(g.record(&mut rec, &a, &a, &a).is_err());
        });
    }
}
