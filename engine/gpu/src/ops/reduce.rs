//! Sum and max of f32 (kernels `reduce_sum_f32`/`reduce_max_f32` in
//! `glsl/reduce.comp`; CPU reference `latentam_reference::reduce`).

use latentam_shaders::{push, REDUCE_MAX_F32, REDUCE_SUM_F32};

use crate::{Buffer, Context, Recorder};
use latentam_base::{Error, Result};
use latentam_shaders::bind;

/// Elements folded per workgroup (THREADS × ITEMS in the kernel).
pub const REDUCE_BLOCK: u64 = 2048;

/// Which reduction.
///
/// ```no_run
/// # use latentam_gpu::{Buffer, Context};
/// # use latentam_gpu::ops::Reducer;
/// # fn f(ctx: &Context, reducer: &Reducer, depths: &Buffer, n: u64, out: &Buffer) -> latentam_gpu::Result<()> {
/// use latentam_gpu::ops::ReduceOp;
///
/// let mut rec = ctx.recorder()?;
/// reducer.record(&mut rec, ReduceOp::Max, depths, n, out)?;
/// rec.submit()?.wait()?;
/// let farthest = ctx.download::<f32>(out)?[0];
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReduceOp {
    /// Sum (0 for no elements).
    Sum,
    /// Maximum (−∞ for no elements).
    Max,
}

/// A reusable multi-pass reduction of up to `max_len` f32 values into one.
///
/// ```no_run
/// use latentam_gpu::{Buffer, Context, ContextOptions};
/// use latentam_gpu::ops::{ReduceOp, Reducer};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let values = ctx.upload_new("example/values", &vec![0.5f32; 10_000])?;
/// let total = Buffer::device(&ctx, "example/total", 4)?;
/// let reducer = Reducer::new(&ctx, 10_000)?;
/// let mut rec = ctx.recorder()?;
/// reducer.record(&mut rec, ReduceOp::Sum, &values, 10_000, &total)?;
/// rec.submit()?.wait()?;
/// assert_eq!(ctx.download::<f32>(&total)?, vec![5000.0]);
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
pub struct Reducer {
    max_len: u64,
    levels: Vec<Buffer>,
}

impl Reducer {
    /// Allocates the intermediate buffers for up to `max_len` elements.
    pub fn new(ctx: &Context, max_len: u64) -> Result<Self> {
        let mut levels = Vec::new();
        let mut len = max_len.div_ceil(REDUCE_BLOCK);
        while len > 1 {
            levels.push(Buffer::device(
                ctx,
                &format!("reduce/level{}", levels.len()),
                len * 4,
            )?);
            len = len.div_ceil(REDUCE_BLOCK);
        }
        Ok(Self { max_len, levels })
    }

    /// Writes the reduction of `src[..n]` to `dst[0]` (f32).
    pub fn record<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        op: ReduceOp,
        src: &'a Buffer,
        n: u64,
        dst: &'a Buffer,
    ) -> Result<()> {
        if n > self.max_len || n * 4 > src.bytes() || dst.bytes() < 4 {
            return Err(Error::bad_input(
                "reduction",
                format!(
                    "{n} elements of `{}` ({} bytes) into `{}` (capacity {})",
                    src.name(),
                    src.bytes(),
                    dst.name(),
                    self.max_len
                ),
            ));
        }
        let mut cur = src;
        let mut len = n;
        let mut level = 0;
        loop {
            let blocks = len.div_ceil(REDUCE_BLOCK).max(1);
            let out = if blocks == 1 {
                dst
            } else {
                &self.levels[level]
            };
            let groups = blocks as u32;
            let n = len as u32;
            match op {
                ReduceOp::Sum => rec.dispatch_linear(
                    &REDUCE_SUM_F32,
                    groups,
                    bind::ReduceBuffers { src: cur, dst: out },
                    &push::Reduce { n },
                )?,
                ReduceOp::Max => rec.dispatch_linear(
                    &REDUCE_MAX_F32,
                    groups,
                    bind::ReduceBuffers { src: cur, dst: out },
                    &push::Reduce { n },
                )?,
            }
            if blocks == 1 {
                return Ok(());
            }
            cur = out;
            len = blocks;
            level += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use crate::testing::{rng, with_context};
    use latentam_reference::reduce;

    #[test]
    fn reductions_match_reference_on_random_lengths() {
        let mut r = rng("reductions_match_reference_on_random_lengths");
        with_context(|ctx| {
            let mut lengths = vec![0u64, 1, 255, 256, 257, 2047, 2048, 2049, 5_000_000];
            lengths.push(r.random_range(1..1_000_000));
            let dst = Buffer::device(ctx, "test/dst", 4).unwrap();
            for n in lengths {
                let data: Vec<f32> = (0..n).map(|_| r.random_range(-1.0f32..1.0)).collect();
                let src = ctx.upload_new("test/src", &data).unwrap();
                let red = Reducer::new(ctx, n).unwrap();
                for op in [ReduceOp::Sum, ReduceOp::Max] {
                    let mut rec = ctx.recorder().unwrap();
                    rec.fill_u32(&dst, 0x7fc0_0000); // NaN poison
                    red.record(&mut rec, op, &src, n, &dst).unwrap();
                    rec.submit().unwrap().wait().unwrap();
                    let got = ctx.download::<f32>(&dst).unwrap()[0];
                    match op {
                        ReduceOp::Sum => {
                            let want = reduce::sum(&data);
                            // f32 tree summation: error grows ~ eps·log2(n)·Σ|x|.
                            let tol =
                                1e-6 * (n as f64).max(1.0).log2().max(1.0) * n as f64 * 0.5 + 1e-6;
                            assert!(
                                (got as f64 - want).abs() <= tol,
                                "sum n={n}: got {got}, want {want} (tol {tol})"
                            );
                        }
                        ReduceOp::Max => {
                            assert_eq!(got, reduce::max(&data), "max n={n}");
                        }
                    }
                }
            }
        });
    }
}
