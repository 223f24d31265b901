//! Adam for one parameter tensor (kernels `glsl/adam_step.comp`,
//! `glsl/adam_count.comp`, `glsl/adam_reset.comp`).

use latentam_shaders::{push, ADAM_COUNT, ADAM_RESET, ADAM_STEP};

use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context, Recorder};
use latentam_shaders::bind;

const THREADS: u64 = 256;

/// Hyper-parameters of one parameter group.
///
/// ```
/// use latentam_core::optim::AdamHyper;
///
/// let mut hyper = AdamHyper::new(0.01, 1e-8);
/// assert_eq!((hyper.beta1, hyper.beta2), (0.9, 0.999));
/// hyper.lr *= 0.5; // decay the rate: set `AdamGroup::hyper` before the next step
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamHyper {
    /// Learning rate.
    pub lr: f32,
    /// First-moment decay β₁.
    pub beta1: f32,
    /// Second-moment decay β₂.
    pub beta2: f32,
    /// Added to √v̂ (3DGS uses 1e-15 for Gaussians; 1e-8 is the usual
    /// choice for dense weights).
    pub eps: f32,
}

impl AdamHyper {
    /// β = (0.9, 0.999) with the given learning rate and ε.
    pub fn new(lr: f32, eps: f32) -> Self {
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps,
        }
    }

    fn validate(&self, name: &str) -> Result<()> {
        let ok = self.lr.is_finite()
            && self.lr >= 0.0
            && (0.0..1.0).contains(&self.beta1)
            && (0.0..1.0).contains(&self.beta2)
            && self.eps.is_finite()
            && self.eps >= 0.0;
        if !ok {
            return Err(Error::bad_input(
                format!("Adam group `{name}`"),
                format!("need lr ≥ 0, 0 ≤ β < 1, ε ≥ 0; got {self:?}"),
            ));
        }
        Ok(())
    }
}

/// Adam state (both moments and a step count per row) for a tensor of up to
/// `rows` rows × `width` columns, updated in place on the GPU.
///
/// Each row keeps its own step count, so bias correction stays right for
/// rows that skip steps (masked: not seen by the current batch) or restart
/// (reset: a replaced dictionary atom). An element whose gradient is NaN or
/// infinite is not updated.
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions};
/// use latentam_core::optim::{AdamGroup, AdamHyper};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let w = ctx.upload_new("W", &vec![0.5f32; 32 * 768])?;
/// let grad = ctx.upload_new("dW", &vec![0.1f32; 32 * 768])?;
/// let adam = AdamGroup::new(&ctx, "W", 32, 768, AdamHyper::new(0.01, 1e-8))?;
/// let mut rec = ctx.recorder()?;
/// adam.record_step(&mut rec, &w, &grad, 32, None)?;
/// rec.submit()?.wait()?;
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct AdamGroup {
    name: String,
    rows: u32,
    width: u32,
    /// The hyper-parameters used by the next recorded step.
    pub hyper: AdamHyper,
    m: Buffer,
    v: Buffer,
    steps: Buffer,
    no_mask: Buffer,
}

impl AdamGroup {
    /// Zero state for `rows` × `width` parameters.
    pub fn new(ctx: &Context, name: &str, rows: u32, width: u32, hyper: AdamHyper) -> Result<Self> {
        hyper.validate(name)?;
        if width == 0 {
            return Err(Error::bad_input(
                format!("Adam group `{name}`"),
                "width must be positive",
            ));
        }
        let elems = (rows.max(1) as u64) * width as u64;
        let buf =
            |what: &str, bytes: u64| Buffer::device(ctx, &format!("adam/{name}/{what}"), bytes);
        let group = Self {
            name: name.to_string(),
            rows,
            width,
            hyper,
            m: buf("m", elems * 4)?,
            v: buf("v", elems * 4)?,
            steps: buf("steps", rows.max(1) as u64 * 4)?,
            no_mask: buf("no_mask", 4)?,
        };
        group.reset_all(ctx)?;
        Ok(group)
    }

    /// Rows of state.
    pub fn rows(&self) -> u32 {
        self.rows
    }

    /// The per-row state buffers with their bytes per row (first moment,
    /// second moment, step count), for moving rows together with their
    /// parameters (e.g. when a local window compacts).
    pub fn state(&self) -> [(&Buffer, u64); 3] {
        let row = self.width as u64 * 4;
        [(&self.m, row), (&self.v, row), (&self.steps, 4)]
    }

    fn check(&self, what: &str, rows: u32, bufs: &[&Buffer], per_row: &[u64]) -> Result<()> {
        if rows > self.rows {
            return Err(Error::bad_input(
                format!("Adam group `{}` ({} rows)", self.name, self.rows),
                format!("{what} of {rows} rows"),
            ));
        }
        for (b, &bytes) in bufs.iter().zip(per_row) {
            b.ensure_bytes(
                rows as u64 * bytes,
                &format!("Adam group `{}` {what}", self.name),
            )?;
        }
        Ok(())
    }

    /// Records one update of the first `rows` rows of `param` from `grad`
    /// (same layout). With a `mask` (one u32 per row), only rows whose mask
    /// is non-zero are updated and advance their step count.
    pub fn record_step<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        param: &'a Buffer,
        grad: &'a Buffer,
        rows: u32,
        mask: Option<&'a Buffer>,
    ) -> Result<()> {
        let row_bytes = self.width as u64 * 4;
        self.check("step", rows, &[param, grad], &[row_bytes, row_bytes])?;
        if let Some(m) = mask {
            self.check("step mask", rows, &[m], &[4])?;
        }
        let elems = rows as u64 * self.width as u64;
        if elems > u32::MAX as u64 {
            return Err(Error::bad_input(
                format!("Adam group `{}`", self.name),
                format!("{elems} elements exceed one dispatch"),
            ));
        }
        let use_mask = mask.is_some() as u32;
        let mask = mask.unwrap_or(&self.no_mask);
        let h = &self.hyper;
        let p = push::AdamStep {
            elems: elems as u32,
            width: self.width,
            use_mask,
            lr: h.lr,
            beta1: h.beta1,
            beta2: h.beta2,
            eps: h.eps,
        };
        rec.dispatch_linear(
            &ADAM_STEP,
            elems.div_ceil(THREADS) as u32,
            bind::AdamStepBuffers {
                param,
                grad,
                m: &self.m,
                v: &self.v,
                steps: &self.steps,
                mask,
            },
            &p,
        )?;
        rec.dispatch_linear(
            &ADAM_COUNT,
            (rows as u64).div_ceil(THREADS) as u32,
            bind::AdamCountBuffers {
                steps: &self.steps,
                mask,
            },
            &push::AdamCount { rows, use_mask },
        )
    }

    /// Records a reset of the moments and step counts of the rows whose flag
    /// in `flags` (one u32 per row, first `rows` rows) is non-zero.
    pub fn record_reset<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        flags: &'a Buffer,
        rows: u32,
    ) -> Result<()> {
        self.check("reset", rows, &[flags], &[4])?;
        let elems = rows as u64 * self.width as u64;
        rec.dispatch_linear(
            &ADAM_RESET,
            elems.div_ceil(THREADS) as u32,
            bind::AdamResetBuffers {
                m: &self.m,
                v: &self.v,
                steps: &self.steps,
                flags,
            },
            &push::AdamReset {
                elems: elems as u32,
                width: self.width,
            },
        )
    }

    /// Forgets all history (moments and step counts to zero), now.
    pub fn reset_all(&self, ctx: &Context) -> Result<()> {
        let mut rec = ctx.recorder()?;
        for b in [&self.m, &self.v, &self.steps] {
            rec.fill_u32(b, 0);
        }
        rec.submit()?.wait()
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use latentam_gpu::testing::{rng, with_context};
    use latentam_reference::adam::AdamState;

    fn reference_hyper(h: &AdamHyper) -> latentam_reference::adam::AdamHyper {
        latentam_reference::adam::AdamHyper {
            lr: h.lr as f64,
            beta1: h.beta1 as f64,
            beta2: h.beta2 as f64,
            eps: h.eps as f64,
        }
    }

    #[test]
    fn adam_matches_reference_with_masks_resets_and_bad_gradients() {
        let mut r = rng("adam_matches_reference_with_masks_resets_and_bad_gradients");
        with_context(|ctx| {
            for (rows, width, hyper) in [
                (1000u32, 3u32, AdamHyper::new(1e-3, 1e-15)),
                (37, 768, AdamHyper::new(0.01, 1e-8)),
                (
                    300,
                    32,
                    AdamHyper {
                        lr: 2.5e-3,
                        beta1: 0.5,
                        beta2: 0.9,
                        eps: 1e-6,
                    },
                ),
            ] {
                let n = (rows * width) as usize;
                let init: Vec<f32> = (0..n).map(|_| r.random_range(-1.0..1.0)).collect();
                let param = ctx.upload_new("test/param", &init).unwrap();
                let adam = AdamGroup::new(ctx, "test", rows, width, hyper).unwrap();
                let mut want: Vec<f64> = init.iter().map(|&v| v as f64).collect();
                let mut state = AdamState::new(rows as usize, width as usize);
                // Only the first `used` rows are in play; the rest must not move.
                let used = rows - rows / 7;
                for step in 0..5 {
                    let mut grad: Vec<f32> = (0..n).map(|_| r.random_range(-1.0..1.0)).collect();
                    if step == 2 {
                        grad[0] = f32::NAN;
                        grad[n / 2] = f32::INFINITY;
                    }
                    let mask: Vec<bool> = (0..rows).map(|_| r.random_bool(0.7)).collect();
                    let use_mask = step % 2 == 1;
                    let gb = ctx.upload_new("test/grad", &grad).unwrap();
                    let mask_u32: Vec<u32> = mask.iter().map(|&b| b as u32).collect();
                    let mb = ctx.upload_new("test/mask", &mask_u32).unwrap();
                    let mut rec = ctx.recorder().unwrap();
                    adam.record_step(&mut rec, &param, &gb, used, use_mask.then_some(&mb))
                        .unwrap();
                    if step == 3 {
                        adam.record_reset(&mut rec, &mb, used).unwrap();
                    }
                    rec.submit().unwrap().wait().unwrap();
                    state.step(
                        &reference_hyper(&hyper),
                        &mut want,
                        &grad,
                        used as usize,
                        use_mask.then_some(&mask[..]),
                    );
                    if step == 3 {
                        state.reset(&mask[..used as usize]);
                    }
                }
                let got = ctx.download::<f32>(&param).unwrap();
                for i in 0..n {
                    // Adam's step is ≈ lr per update; compare at 1e-3 of it.
                    let tol = 1e-5 + hyper.lr as f64 * 1e-3;
                    assert!(
                        (got[i] as f64 - want[i]).abs() <= tol,
                        "{rows}x{width}: param[{i}] = {}, want {}",
                        got[i],
                        want[i]
                    );
                    if i >= (used * width) as usize {
                        assert_eq!(got[i], init[i], "row beyond the batch moved");
                    }
                }
                assert!(got.iter().all(|v| v.is_finite()));
            }
        });
    }

    #[test]
    fn bad_hyper_parameters_and_sizes_are_rejected() {
        with_context(|ctx| {
            assert!(AdamGroup::new(ctx, "x", 4, 4, AdamHyper::new(f32::NAN, 1e-8)).is_err());
            assert!(AdamGroup::new(
                ctx,
                "x",
                4,
                4,
                AdamHyper {
                    beta1: 1.0,
                    ..AdamHyper::new(0.1, 1e-8)
                }
            )
            .is_err());
            assert!(AdamGroup::new(ctx, "x", 4, 0, AdamHyper::new(0.1, 1e-8)).is_err());
            let adam = AdamGroup::new(ctx, "x", 4, 4, AdamHyper::new(0.1, 1e-8)).unwrap();
            let small = Buffer::device(ctx, "test/small", 32).unwrap();
            let big = Buffer::device(ctx, "test/big", 1024).unwrap();
            let mut rec = ctx.recorder().unwrap();
            assert!(adam.record_step(&mut rec, &big, &big, 5, None).is_err());
            assert!(adam.record_step(&mut rec, &small, &big, 4, None).is_err());
            assert!(adam
                .record_step(&mut rec, &big, &big, 4, Some(&small))
                .is_ok());
        });
    }
}
