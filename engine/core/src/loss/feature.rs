//! Feature loss and trust-region penalty (kernels `glsl/feature_loss.comp`,
//! `glsl/trust_region.comp`; CPU reference `latentam_reference::loss`).

use latentam_shaders::{push, FEATURE_LOSS, TRUST_REGION};

use super::LossWeights;
use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context, Readback, Recorder};
use latentam_shaders::bind;

/// Norms below this are clamped in the cosine (an all-zero prediction or
/// target has a defined loss and gradient).
pub const COSINE_EPS: f32 = 1e-8;

fn check_rows(what: &str, rows: u32, capacity: u32) -> Result<()> {
    if rows > capacity {
        return Err(Error::bad_input(
            what,
            format!("{rows} rows, sized for {capacity}"),
        ));
    }
    Ok(())
}

/// The feature loss between decoded region embeddings F̂ and their targets F:
/// `λ_f · Σ_m w_m (λ_cos (1 − cos(F̂_m, F_m)) + λ_2 ‖F̂_m − F_m‖² / d_f)`,
/// and ∂L/∂F̂ for the decoder's backward pass.
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions};
/// use latentam_core::loss::{mean_per_view_weights, FeatureLoss, LossWeights};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let loss = FeatureLoss::new(&ctx, 3, 64, LossWeights::default())?;
/// let pred = ctx.upload_new("pred", &vec![0.5f32; 3 * 64])?;
/// let target = ctx.upload_new("target", &vec![0.125f32; 3 * 64])?;
/// let weights = ctx.upload_new("w", &mean_per_view_weights(&[2, 1]))?;
/// let mut rec = ctx.recorder()?;
/// loss.record(&mut rec, &pred, &target, &weights, 3)?;
/// let total = loss.record_readback(&mut rec, 3)?;
/// rec.submit()?.wait()?;
/// println!("feature loss {}", FeatureLoss::sum(&total)?); // gradient in loss.grad()
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct FeatureLoss {
    max_rows: u32,
    dim: u32,
    weights: LossWeights,
    grad: Buffer,
    row_loss: Buffer,
}

impl FeatureLoss {
    /// Workspace for up to `max_rows` regions of dimension `dim`.
    pub fn new(ctx: &Context, max_rows: u32, dim: u32, weights: LossWeights) -> Result<Self> {
        let rows = max_rows.max(1) as u64;
        Ok(Self {
            max_rows,
            dim,
            weights,
            grad: Buffer::device(ctx, "feature_loss/grad", rows * dim as u64 * 4)?,
            row_loss: Buffer::device(ctx, "feature_loss/rows", rows * 4)?,
        })
    }

    /// ∂L/∂F̂ of the last recorded evaluation (rows × d_f).
    pub fn grad(&self) -> &Buffer {
        &self.grad
    }

    /// Records the loss of `rows` regions: predictions and targets are
    /// rows × d_f, `row_weights` one f32 per row (0 for a region without a
    /// valid target; see [`super::mean_per_view_weights`]).
    pub fn record<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        pred: &'a Buffer,
        target: &'a Buffer,
        row_weights: &'a Buffer,
        rows: u32,
    ) -> Result<()> {
        check_rows("feature loss", rows, self.max_rows)?;
        let elems = rows as u64 * self.dim as u64 * 4;
        pred.ensure_bytes(elems, "feature loss predictions")?;
        target.ensure_bytes(elems, "feature loss targets")?;
        row_weights.ensure_bytes(rows as u64 * 4, "feature loss row weights")?;
        let w = &self.weights;
        let p = push::FeatureLoss {
            rows,
            cols: self.dim,
            lambda_cos: w.feature * w.cosine,
            lambda_l2: w.feature * w.l2,
            eps: COSINE_EPS,
        };
        rec.dispatch_linear(
            &FEATURE_LOSS,
            rows,
            bind::FeatureLossBuffers {
                pred,
                target,
                weight: row_weights,
                grad: &self.grad,
                row_loss: &self.row_loss,
            },
            &p,
        )
    }

    /// Records a download of the per-row losses of the last `rows` regions;
    /// [`Self::sum`] totals them once the submission has completed.
    pub fn record_readback<'a>(&'a self, rec: &mut Recorder<'a>, rows: u32) -> Result<Readback> {
        check_rows("feature loss readback", rows, self.max_rows)?;
        rec.download(&self.row_loss, 0, rows as u64 * 4)
    }

    /// Sum in f64 of a per-row loss readback.
    pub fn sum(readback: &Readback) -> Result<f64> {
        Ok(readback.read::<f32>()?.iter().map(|&v| v as f64).sum())
    }
}

/// Keeps each atom within `δ` of its k-means anchor:
/// `λ_f · λ_D · Σ_k max(0, ‖D_k − D⁰_k‖ − δ)`, its gradient added to ∂L/∂D.
///
/// ```no_run
/// # use latentam_gpu::{Buffer, Context};
/// # fn f(ctx: &Context, dictionary: &Buffer, anchor: &Buffer, grad: &Buffer) -> latentam_core::Result<()> {
/// use latentam_core::loss::{FeatureLoss, LossWeights, TrustRegion};
///
/// let trust = TrustRegion::new(ctx, 2000, 512, LossWeights::default())?;
/// let mut rec = ctx.recorder()?;
/// trust.record(&mut rec, dictionary, anchor, grad, 2000)?; // adds to ∂L/∂D
/// let penalties = trust.record_readback(&mut rec, 2000)?;
/// rec.submit()?.wait()?;
/// println!("trust-region loss {}", FeatureLoss::sum(&penalties)?);
/// # Ok(())
/// # }
/// ```
pub struct TrustRegion {
    max_atoms: u32,
    dim: u32,
    weights: LossWeights,
    atom_loss: Buffer,
}

impl TrustRegion {
    /// Workspace for up to `max_atoms` atoms of dimension `dim`.
    pub fn new(ctx: &Context, max_atoms: u32, dim: u32, weights: LossWeights) -> Result<Self> {
        Ok(Self {
            max_atoms,
            dim,
            weights,
            atom_loss: Buffer::device(ctx, "trust_region/atoms", max_atoms.max(1) as u64 * 4)?,
        })
    }

    /// Records the penalty of the first `atoms` atoms of `dictionary` against
    /// `anchor`, adding its gradient to `grad` (atoms × d_f).
    pub fn record<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        dictionary: &'a Buffer,
        anchor: &'a Buffer,
        grad: &'a Buffer,
        atoms: u32,
    ) -> Result<()> {
        check_rows("trust region", atoms, self.max_atoms)?;
        let elems = atoms as u64 * self.dim as u64 * 4;
        for b in [dictionary, anchor, grad] {
            b.ensure_bytes(elems, "trust region")?;
        }
        let w = &self.weights;
        let p = push::TrustRegion {
            rows: atoms,
            cols: self.dim,
            lambda: w.feature * w.trust_region,
            radius: w.trust_radius,
        };
        rec.dispatch_linear(
            &TRUST_REGION,
            atoms,
            bind::TrustRegionBuffers {
                atoms: dictionary,
                anchor,
                grad,
                atom_loss: &self.atom_loss,
            },
            &p,
        )
    }

    /// Records a download of the per-atom penalties (sum with
    /// [`FeatureLoss::sum`]).
    pub fn record_readback<'a>(&'a self, rec: &mut Recorder<'a>, atoms: u32) -> Result<Readback> {
        check_rows("trust region readback", atoms, self.max_atoms)?;
        rec.download(&self.atom_loss, 0, atoms as u64 * 4)
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use crate::loss::mean_per_view_weights;
    use latentam_gpu::testing::{rng, with_context};
    use latentam_reference::loss as reference;

    fn close(what: &str, got: &[f32], want: &[f64], rel: f64) {
        let scale = want.iter().fold(1e-6f64, |m, v| m.max(v.abs()));
        for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
            assert!(
                (g as f64 - w).abs() <= rel * scale,
                "{what}[{i}] = {g}, want {w}"
            );
        }
    }

    #[test]
    fn feature_loss_matches_reference() {
        let mut r = rng("feature_loss_matches_reference");
        with_context(|ctx| {
            for (counts, dim) in [
                (vec![1u32], 64u32),
                (vec![7, 0, 30], 768),
                (vec![3, 5], 257),
            ] {
                let rows: u32 = counts.iter().sum();
                let n = (rows * dim) as usize;
                let mut pred: Vec<f32> = (0..n).map(|_| r.random_range(-1.0..1.0)).collect();
                let target: Vec<f32> = (0..n).map(|_| r.random_range(-0.1..0.1)).collect();
                // An all-zero prediction row: the clamped cosine branch.
                pred[..dim as usize].iter_mut().for_each(|v| *v = 0.0);
                let weights = mean_per_view_weights(&counts);
                let w = LossWeights::default();
                let loss = FeatureLoss::new(ctx, rows, dim, w).unwrap();
                let pb = ctx.upload_new("test/pred", &pred).unwrap();
                let tb = ctx.upload_new("test/target", &target).unwrap();
                let wb = ctx.upload_new("test/weights", &weights).unwrap();
                let mut rec = ctx.recorder().unwrap();
                rec.fill_u32(loss.grad(), 0x7fc0_0000);
                loss.record(&mut rec, &pb, &tb, &wb, rows).unwrap();
                let rb = loss.record_readback(&mut rec, rows).unwrap();
                rec.submit().unwrap().wait().unwrap();
                let (want_loss, want_grad) = reference::feature_loss(
                    &pred,
                    &target,
                    &weights,
                    dim as usize,
                    (w.feature * w.cosine) as f64,
                    (w.feature * w.l2) as f64,
                    COSINE_EPS as f64,
                );
                close("row loss", &rb.read::<f32>().unwrap(), &want_loss, 1e-5);
                let got = ctx.download::<f32>(loss.grad()).unwrap();
                close("grad", &got[..n], &want_grad, 1e-4);
                let total = FeatureLoss::sum(&rb).unwrap();
                let want: f64 = want_loss.iter().sum();
                assert!((total - want).abs() <= 1e-5 * want.abs().max(1.0));
            }
        });
    }

    #[test]
    fn trust_region_matches_reference_and_adds_to_the_gradient() {
        let mut r = rng("trust_region_matches_reference_and_adds_to_the_gradient");
        with_context(|ctx| {
            let (atoms, dim) = (300u32, 768u32);
            let n = (atoms * dim) as usize;
            let anchor: Vec<f32> = (0..n).map(|_| r.random_range(-1.0..1.0)).collect();
            // Per-atom displacement scales straddling the 0.1 radius.
            let atom_scale: Vec<f32> = (0..atoms).map(|_| r.random_range(0.0..0.3)).collect();
            let dict: Vec<f32> = (0..n)
                .map(|i| {
                    let s = atom_scale[i / dim as usize] / (dim as f32).sqrt();
                    anchor[i] + s * r.random_range(-1.7f32..1.7)
                })
                .collect();
            let prior: Vec<f32> = (0..n).map(|_| r.random_range(-1.0..1.0)).collect();
            let w = LossWeights::default();
            let tr = TrustRegion::new(ctx, atoms, dim, w).unwrap();
            let db = ctx.upload_new("test/d", &dict).unwrap();
            let ab = ctx.upload_new("test/d0", &anchor).unwrap();
            let gb = ctx.upload_new("test/grad", &prior).unwrap();
            let mut rec = ctx.recorder().unwrap();
            tr.record(&mut rec, &db, &ab, &gb, atoms).unwrap();
            let rb = tr.record_readback(&mut rec, atoms).unwrap();
            rec.submit().unwrap().wait().unwrap();
            let (want_loss, want_grad) = reference::trust_region(
                &dict,
                &anchor,
                dim as usize,
                (w.feature * w.trust_region) as f64,
                w.trust_radius as f64,
            );
            let active = want_loss.iter().filter(|&&l| l > 0.0).count();
            assert!(
                active > 10 && active < atoms as usize - 10,
                "{active} active atoms"
            );
            close("atom loss", &rb.read::<f32>().unwrap(), &want_loss, 1e-5);
            let got = ctx.download::<f32>(&gb).unwrap();
            let want: Vec<f64> = want_grad
                .iter()
                .zip(&prior)
                .map(|(g, &p)| g + p as f64)
                .collect();
            close("grad", &got, &want, 1e-5);
        });
    }

    #[test]
    fn oversized_batches_are_rejected() {
        with_context(|ctx| {
            let loss = FeatureLoss::new(ctx, 2, 64, LossWeights::default()).unwrap();
            let b = Buffer::device(ctx, "test/b", 4 * 64 * 4).unwrap();
            let small = Buffer::device(ctx, "test/small", 64).unwrap();
            let mut rec = ctx.recorder().unwrap();
            assert!(loss.record(&mut rec, &b, &b, &b, 3).is_err());
            assert!(loss.record(&mut rec, &small, &b, &b, 2).is_err());
        });
    }
}
