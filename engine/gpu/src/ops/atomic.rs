//! Float scatter-add: native float atomics where the device has them, a
//! compare-and-swap loop otherwise (kernels `atomic_add_f32` and
//! `atomic_add_f32_cas`; CPU reference `latentam_reference::atomic`).

use latentam_shaders::{push, ATOMIC_ADD_F32, ATOMIC_ADD_F32_CAS};

use crate::{Buffer, Recorder};
use latentam_base::Result;
use latentam_shaders::bind;

/// Threads per workgroup of both kernels.
pub const SCATTER_THREADS: u64 = 256;

/// Records `acc[targets[i]] += values[i]` for i < n, with whichever float
/// atomic path the context selected at start-up. Targets must be in range of
/// `acc` (the kernel does not check them).
pub fn scatter_add_f32<'a>(
    rec: &mut Recorder<'a>,
    values: &'a Buffer,
    targets: &'a Buffer,
    acc: &'a Buffer,
    n: u64,
) -> Result<()> {
    values.ensure_bytes(n * 4, "scatter-add values")?;
    targets.ensure_bytes(n * 4, "scatter-add targets")?;
    let groups = n.div_ceil(SCATTER_THREADS) as u32;
    let p = push::ScatterAdd { n: n as u32 };
    if rec.info().native_float_atomics {
        rec.dispatch_linear(
            &ATOMIC_ADD_F32,
            groups,
            bind::ScatterAddBuffers {
                values,
                targets,
                acc,
            },
            &p,
        )
    } else {
        rec.dispatch_linear(
            &ATOMIC_ADD_F32_CAS,
            groups,
            bind::ScatterAddBuffers {
                values,
                targets,
                acc,
            },
            &p,
        )
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use crate::testing::{rng, with_cas_atomics, with_context};
    use crate::Context;
    use latentam_reference::atomic::scatter_add;

    fn check(ctx: &Context, r: &mut impl Rng) {
        // Heavy contention: 200k adds into 37 bins.
        let n = 200_000usize;
        let bins = 37usize;
        let values: Vec<f32> = (0..n).map(|_| r.random_range(-1.0..1.0)).collect();
        let targets: Vec<u32> = (0..n).map(|_| r.random_range(0..bins as u32)).collect();
        let vb = ctx.upload_new("test/values", &values).unwrap();
        let tb = ctx.upload_new("test/targets", &targets).unwrap();
        let acc = Buffer::device(ctx, "test/acc", (bins * 4) as u64).unwrap();
        let mut rec = ctx.recorder().unwrap();
        rec.fill_u32(&acc, 0);
        scatter_add_f32(&mut rec, &vb, &tb, &acc, n as u64).unwrap();
        rec.submit().unwrap().wait().unwrap();
        let got = ctx.download::<f32>(&acc).unwrap();
        let want = scatter_add(&values, &targets, bins);
        for b in 0..bins {
            // ~5400 sequential f32 adds of |x| < 1 into one bin.
            assert!(
                (got[b] as f64 - want[b]).abs() < 2e-2,
                "bin {b}: got {}, want {}",
                got[b],
                want[b]
            );
        }
    }

    #[test]
    fn native_float_atomics_are_detected_and_correct() {
        let mut r = rng("native_float_atomics_are_detected_and_correct");
        with_context(|ctx| {
            // lavapipe and current desktop drivers expose the feature; if a
            // device does not, this checks the automatic fallback instead.
            eprintln!("native float atomics: {}", ctx.info().native_float_atomics);
            check(ctx, &mut r);
        });
    }

    #[test]
    fn compare_and_swap_fallback_is_correct() {
        let mut r = rng("compare_and_swap_fallback_is_correct");
        with_cas_atomics(|ctx| {
            assert!(!ctx.info().native_float_atomics);
            check(ctx, &mut r);
        });
    }

    #[test]
    fn kernels_needing_float_atomics_are_refused_where_they_are_off() {
        with_cas_atomics(|ctx| {
            // Warming up compiles only what the device runs: no pipeline of
            // a native-atomic variant on a device without the extension.
            // (Column-layout blending kernels are left out: a GPU's
            // compiler may reject the largest, and the rasterizer then
            // takes the pixel ones.)
            let pixel_layout = |k: &latentam_shaders::Kernel| !k.is_column_layout();
            let runnable = latentam_shaders::ALL
                .iter()
                .filter(|k| pixel_layout(k) && !k.requires.float_atomics && ctx.info().can_run(k))
                .count();
            assert!(runnable < latentam_shaders::ALL.len());
            assert_eq!(ctx.warm_up_only(pixel_layout).unwrap(), runnable);
            let values = ctx.upload_new("test/values", &[1.0f32]).unwrap();
            let targets = ctx.upload_new("test/targets", &[0u32]).unwrap();
            let acc = Buffer::device(ctx, "test/acc", 4).unwrap();
            let mut rec = ctx.recorder().unwrap();
            let p = push::ScatterAdd { n: 1 };
            let e = rec
                .dispatch_linear(
                    &ATOMIC_ADD_F32,
                    1,
                    bind::ScatterAddBuffers {
                        values: &values,
                        targets: &targets,
                        acc: &acc,
                    },
                    &p,
                )
                .unwrap_err();
            assert!(e.to_string().contains("float atomic add"), "{e}");
        });
    }
}
