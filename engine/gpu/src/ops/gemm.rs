//! Single-precision matrix products, in two kernels with one contract
//! (CPU reference `latentam_reference::gemm`):
//!
//! * [`GemmKernel::Tiled`] (`gemm_nn`, `gemm_tn`, `gemm_nt` in
//!   `glsl/gemm.comp`): shared-memory tiles, for GPUs;
//! * [`GemmKernel::Blocked`] (`gemm_blocked_*` in `glsl/gemm_blocked.comp`):
//!   8×8 register blocks and no barriers, for CPU drivers, where shared
//!   memory and barriers cost more than they save; from 16-byte loads when
//!   the shape allows ([`Gemm::vector_loads_fit`]), else the `_scalar`
//!   variants.
//!
//! [`Gemm::record`] picks by the device's type and the product's shape.

use ash::vk::PhysicalDeviceType;
use latentam_shaders::{
    push, KernelDef, GEMM_BLOCKED_NN, GEMM_BLOCKED_NN_SCALAR, GEMM_BLOCKED_NT,
    GEMM_BLOCKED_NT_SCALAR, GEMM_BLOCKED_TN, GEMM_BLOCKED_TN_SCALAR, GEMM_NN, GEMM_NT, GEMM_TN,
};

use crate::{Buffer, Recorder};
use latentam_base::{Error, Result};
use latentam_shaders::bind;

/// Which operands are used transposed.
///
/// ```
/// use latentam_gpu::ops::{Gemm, Transpose};
///
/// // Aᵀ·B with A stored k×m (256×64) and B k×n (256×32): a weight gradient.
/// let grad = Gemm { transpose: Transpose::A, m: 64, n: 32, k: 256, alpha: 1.0, beta: 1.0 };
/// assert!(grad.vector_loads_fit());
/// assert_eq!(grad.flops(), 2.0 * 64.0 * 32.0 * 256.0);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transpose {
    /// A·B with A m×k, B k×n.
    None,
    /// Aᵀ·B with A stored k×m.
    A,
    /// A·Bᵀ with B stored n×k.
    B,
}

/// Rows and columns of C computed per workgroup (by either kernel).
pub use latentam_shaders::shared::GEMM_TILE;

/// Which kernel computes a product.
///
/// ```
/// use ash::vk::PhysicalDeviceType;
/// use latentam_gpu::ops::GemmKernel;
///
/// assert_eq!(GemmKernel::for_device(PhysicalDeviceType::CPU), GemmKernel::Blocked);
/// assert_eq!(GemmKernel::for_device(PhysicalDeviceType::DISCRETE_GPU), GemmKernel::Tiled);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GemmKernel {
    /// Shared-memory tiles: any shape; the choice on GPUs.
    Tiled,
    /// Register blocks: any shape; the choice on CPU drivers.
    Blocked,
}

impl GemmKernel {
    /// The kernel suited to a device of type `device_type`.
    pub fn for_device(device_type: PhysicalDeviceType) -> Self {
        if device_type == PhysicalDeviceType::CPU {
            GemmKernel::Blocked
        } else {
            GemmKernel::Tiled
        }
    }

    /// Whether `kernel` (a kernel of the catalogue) is one of this family's
    /// variants: what building ahead of use needs, so that a device builds
    /// only the family it dispatches.
    ///
    /// ```
    /// use latentam_gpu::ops::GemmKernel;
    ///
    /// assert!(GemmKernel::Blocked.includes(&latentam_shaders::GEMM_BLOCKED_TN_SCALAR.kernel));
    /// assert!(!GemmKernel::Tiled.includes(&latentam_shaders::GEMM_BLOCKED_TN.kernel));
    /// ```
    pub fn includes(self, kernel: &latentam_shaders::Kernel) -> bool {
        let family: &[&KernelDef<push::Gemm, bind::Gemm>] = match self {
            GemmKernel::Tiled => &[&GEMM_NN, &GEMM_TN, &GEMM_NT],
            GemmKernel::Blocked => &[
                &GEMM_BLOCKED_NN,
                &GEMM_BLOCKED_TN,
                &GEMM_BLOCKED_NT,
                &GEMM_BLOCKED_NN_SCALAR,
                &GEMM_BLOCKED_TN_SCALAR,
                &GEMM_BLOCKED_NT_SCALAR,
            ],
        };
        family.iter().any(|d| d.kernel.name == kernel.name)
    }
}

/// Shape and scaling of one product `C = alpha·op(A)·op(B) + beta·C`
/// (row-major, contiguous; op(A) is m×k, op(B) is k×n).
///
/// ```no_run
/// use latentam_gpu::{Buffer, Context, ContextOptions};
/// use latentam_gpu::ops::{Gemm, Transpose};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let a = ctx.upload_new("example/a", &[1.0f32; 64 * 128])?;
/// let b = ctx.upload_new("example/b", &[0.5f32; 128 * 32])?;
/// let c = Buffer::device(&ctx, "example/c", 64 * 32 * 4)?;
/// // C (64×32) = A (64×128) · B (128×32), overwriting C.
/// let gemm = Gemm { transpose: Transpose::None, m: 64, n: 32, k: 128, alpha: 1.0, beta: 0.0 };
/// let mut rec = ctx.recorder()?;
/// gemm.record(&mut rec, &a, &b, &c)?;
/// rec.submit()?.wait()?;
/// assert_eq!(ctx.download::<f32>(&c)?[0], 64.0);
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
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

    /// Whether [`GemmKernel::Blocked`] can read this product's operands 16
    /// bytes at a time: its loads run along K for A (transposed: along M)
    /// and along N for B (transposed: along K), which must be multiples of
    /// 4.
    pub fn vector_loads_fit(&self) -> bool {
        let four = |x: u32| x.is_multiple_of(4);
        match self.transpose {
            Transpose::None => four(self.k) && four(self.n),
            Transpose::A => four(self.m) && four(self.n),
            Transpose::B => four(self.k),
        }
    }

    /// The kernel [`Gemm::record`] uses on a device of type `device_type`.
    pub fn kernel_on(&self, device_type: PhysicalDeviceType) -> GemmKernel {
        GemmKernel::for_device(device_type)
    }

    /// Records the product with the kernel suited to the device and shape.
    pub fn record<'a>(
        &self,
        rec: &mut Recorder<'a>,
        a: &'a Buffer,
        b: &'a Buffer,
        c: &'a Buffer,
    ) -> Result<()> {
        let kernel = self.kernel_on(rec.info().device_type);
        self.record_with(rec, kernel, a, b, c)
    }

    /// Records the product with `kernel`.
    pub fn record_with<'a>(
        &self,
        rec: &mut Recorder<'a>,
        kernel: GemmKernel,
        a: &'a Buffer,
        b: &'a Buffer,
        c: &'a Buffer,
    ) -> Result<()> {
        let (def, p) = self.kernel_and_push(kernel, a, b, c)?;
        rec.dispatch(def, self.groups(), bind::GemmBuffers { a, b, c }, &p)
    }

    /// Workgroups of the product, either kernel: what an indirect
    /// dispatch's counts must be for it to run.
    pub fn groups(&self) -> [u32; 3] {
        // Both kernels cover a GEMM_TILE × GEMM_TILE tile per workgroup.
        [self.n.div_ceil(GEMM_TILE), self.m.div_ceil(GEMM_TILE), 1]
    }

    /// Records the product with the device's kernel, run only if the GPU
    /// finds [`Self::groups`] at byte `offset` of `args` when it gets there
    /// (zero groups skip it; see [`Recorder::dispatch_indirect`]).
    pub fn record_indirect<'a>(
        &self,
        rec: &mut Recorder<'a>,
        a: &'a Buffer,
        b: &'a Buffer,
        c: &'a Buffer,
        args: &'a Buffer,
        offset: u64,
    ) -> Result<()> {
        let max = rec.info().max_workgroup_count;
        if self.groups().iter().zip(max).any(|(g, m)| *g > m) {
            return Err(Error::Unsupported(format!(
                "GEMM {}x{}x{}: {:?} workgroups exceed the device limit {max:?}",
                self.m,
                self.n,
                self.k,
                self.groups()
            )));
        }
        let kernel = self.kernel_on(rec.info().device_type);
        let (def, p) = self.kernel_and_push(kernel, a, b, c)?;
        rec.dispatch_indirect(def, args, offset, bind::GemmBuffers { a, b, c }, &p)
    }

    fn kernel_and_push(
        &self,
        kernel: GemmKernel,
        a: &Buffer,
        b: &Buffer,
        c: &Buffer,
    ) -> Result<(&'static KernelDef<push::Gemm, bind::Gemm>, push::Gemm)> {
        let (m, n, k) = (self.m as u64, self.n as u64, self.k as u64);
        for (buf, elems, what) in [(a, m * k, "A"), (b, k * n, "B"), (c, m * n, "C")] {
            buf.ensure_bytes(elems * 4, &format!("GEMM {m}x{n}x{k} operand {what}"))?;
        }
        let (lda, ldb) = match self.transpose {
            Transpose::None => (self.k, self.n),
            Transpose::A => (self.m, self.n),
            Transpose::B => (self.k, self.k),
        };
        let p = push::Gemm {
            m: self.m,
            n: self.n,
            k: self.k,
            lda,
            ldb,
            ldc: self.n,
            alpha: self.alpha,
            beta: self.beta,
        };
        let def: &'static KernelDef<push::Gemm, bind::Gemm> =
            match (kernel, self.transpose, self.vector_loads_fit()) {
                (GemmKernel::Tiled, Transpose::None, _) => &GEMM_NN,
                (GemmKernel::Tiled, Transpose::A, _) => &GEMM_TN,
                (GemmKernel::Tiled, Transpose::B, _) => &GEMM_NT,
                (GemmKernel::Blocked, Transpose::None, true) => &GEMM_BLOCKED_NN,
                (GemmKernel::Blocked, Transpose::A, true) => &GEMM_BLOCKED_TN,
                (GemmKernel::Blocked, Transpose::B, true) => &GEMM_BLOCKED_NT,
                (GemmKernel::Blocked, Transpose::None, false) => &GEMM_BLOCKED_NN_SCALAR,
                (GemmKernel::Blocked, Transpose::A, false) => &GEMM_BLOCKED_TN_SCALAR,
                (GemmKernel::Blocked, Transpose::B, false) => &GEMM_BLOCKED_NT_SCALAR,
            };
        Ok((def, p))
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use crate::testing::{rng, with_context};
    use latentam_reference::gemm::{gemm, Transpose as RefTranspose};

    /// The reference's name for the same operand layout.
    fn reference(t: Transpose) -> RefTranspose {
        match t {
            Transpose::None => RefTranspose::None,
            Transpose::A => RefTranspose::A,
            Transpose::B => RefTranspose::B,
        }
    }

    #[test]
    fn gemm_variants_match_reference_on_random_shapes() {
        let mut r = rng("gemm_variants_match_reference_on_random_shapes");
        with_context(|ctx| {
            // Odd shapes (the blocked kernel's scalar loads, K tails) and
            // multiples of 4 (its 16-byte loads) with edges inside a block
            // (4, 12, 68) and inside a tile (132).
            let mut shapes = vec![
                (1u32, 1u32, 1u32),
                (64, 64, 16),
                (65, 63, 17),
                (3, 130, 200),
                (4, 4, 4),
                (12, 68, 8),
                (132, 20, 36),
                (37, 132, 100),
            ];
            for _ in 0..3 {
                shapes.push((
                    r.random_range(1..150),
                    r.random_range(1..150),
                    r.random_range(1..300),
                ));
                let four = |r: &mut rand_chacha::ChaCha8Rng, hi: u32| 4 * r.random_range(1..hi);
                shapes.push((four(&mut r, 40), four(&mut r, 40), four(&mut r, 80)));
            }
            for (m, n, k) in shapes {
                for (t, kernel) in [Transpose::None, Transpose::A, Transpose::B]
                    .into_iter()
                    .flat_map(|t| [(t, GemmKernel::Tiled), (t, GemmKernel::Blocked)])
                {
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
                        g.record_with(&mut rec, kernel, &ab, &bb, &cb).unwrap();
                        rec.submit().unwrap().wait().unwrap();
                        let got = ctx.download::<f32>(&cb).unwrap();
                        gemm(
                            reference(t),
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
                                "{kernel:?} {t:?} {m}x{n}x{k} alpha={alpha} beta={beta}: C[{i}] = {} want {}",
                                got[i],
                                c[i]
                            );
                        }
                    }
                }
            }
        });
    }

    /// The counts are written on the GPU in the same batch as the product
    /// that reads them: the full grid computes every tile (the grid spans
    /// several workgroups both ways), zero groups leave C as it was.
    #[test]
    fn gemm_runs_only_when_its_indirect_counts_say_so() {
        let mut r = rng("gemm_runs_only_when_its_indirect_counts_say_so");
        with_context(|ctx| {
            let (m, n, k) = (70u32, 90u32, 36u32);
            let a: Vec<f32> = (0..m * k).map(|_| r.random_range(-1.0..1.0)).collect();
            let b: Vec<f32> = (0..k * n).map(|_| r.random_range(-1.0..1.0)).collect();
            let ab = ctx.upload_new("test/a", &a).unwrap();
            let bb = ctx.upload_new("test/b", &b).unwrap();
            let g = Gemm {
                transpose: Transpose::None,
                m,
                n,
                k,
                alpha: 1.0,
                beta: 0.0,
            };
            assert!(g.groups()[0] > 1 && g.groups()[1] > 1);
            let mut want = vec![0.0f32; (m * n) as usize];
            gemm(
                RefTranspose::None,
                m as usize,
                n as usize,
                k as usize,
                1.0,
                &a,
                &b,
                0.0,
                &mut want,
            );
            let args = Buffer::device(ctx, "test/args", 32).unwrap();
            for run in [true, false] {
                let cb = Buffer::device(ctx, "test/c", (m * n * 4) as u64).unwrap();
                let counts = if run { g.groups() } else { [0, 1, 1] };
                let mut rec = ctx.recorder().unwrap();
                rec.fill_u32(&cb, 0x7fc0_0000);
                rec.upload(&args, 16, &counts).unwrap();
                g.record_indirect(&mut rec, &ab, &bb, &cb, &args, 16)
                    .unwrap();
                rec.submit().unwrap().wait().unwrap();
                let got = ctx.download::<f32>(&cb).unwrap();
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    if run {
                        assert!((g - w).abs() <= 1e-4, "C[{i}] = {g} want {w}");
                    } else {
                        assert!(g.is_nan(), "C[{i}] = {g} written with zero groups");
                    }
                }
            }
            let cb = Buffer::device(ctx, "test/c", (m * n * 4) as u64).unwrap();
            let mut rec = ctx.recorder().unwrap();
            let err = g
                .record_indirect(&mut rec, &ab, &bb, &cb, &args, 2)
                .unwrap_err();
            assert!(err.to_string().contains("multiple of 4"), "{err}");
            assert!(g
                .record_indirect(&mut rec, &ab, &bb, &cb, &args, 24)
                .is_err());
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
