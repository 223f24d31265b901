//! Adam over every Gaussian parameter field, one group per field.

use super::adam::{AdamGroup, AdamHyper};
use crate::splat::{GaussianBuffers, FIELD_WIDTHS};
use latentam_base::settings;
use latentam_base::Result;
use latentam_gpu::{Buffer, Context, Recorder};

settings! {
    /// Learning rates per Gaussian field (the paper gives none: GS-ICP's values for
    /// means, scales and rotations). Online, a Gaussian gets one Adam step per
    /// keyframe batch that sees it, so the rates of what the loss must still
    /// change are above the offline methods' (measured on the demo and on
    /// 7-Scenes, see docs/quality.md's ablation): queries 0.1 (offline 2.5e-3, at
    /// which queries stayed near their start: per-pixel mIoU 0.085 on the demo
    /// scene), colours 0.005 (7e-4 before: +0.4 dB on 7-Scenes; 0.02 and 0.05
    /// fit the newest keyframe at the expense of the others) and opacity 0.2
    /// (0.05 before: +0.2 dB).
    ///
    /// ```
    /// use latentam_core::optim::GaussianLearningRates;
    ///
    /// // Let the tracker's poses be refined too.
    /// let lrs = GaussianLearningRates { means: 1.6e-4, ..Default::default() };
    /// assert_eq!(lrs.queries, 0.1);
    /// ```
    #[derive(Copy)]
    pub struct GaussianLearningRates {
        /// Means (positions). Effectively frozen: the poses come from the
        /// tracker.
        pub means: f32 = 4e-6 => value().range(0.0, MAX_LEARNING_RATE),
        /// Log-scales.
        pub log_scales: f32 = 5e-3 => value().range(0.0, MAX_LEARNING_RATE),
        /// Rotation quaternions.
        pub quats: f32 = 1e-3 => value().range(0.0, MAX_LEARNING_RATE),
        /// RGB colours.
        pub colors: f32 = 5e-3 => value().range(0.0, MAX_LEARNING_RATE),
        /// Opacity logits.
        pub opacity: f32 = 0.2 => value().range(0.0, MAX_LEARNING_RATE),
        /// Latent queries.
        pub queries: f32 = 0.1 => value().range(0.0, MAX_LEARNING_RATE),
    }
}

/// Largest learning rate: far beyond any useful value, a step overflows
/// f32.
pub const MAX_LEARNING_RATE: f32 = 10.0;

impl GaussianLearningRates {
    fn in_field_order(&self) -> [f32; 6] {
        [
            self.means,
            self.log_scales,
            self.quats,
            self.colors,
            self.opacity,
            self.queries,
        ]
    }
}

/// Adam state for `capacity` Gaussians (ε = 1e-15, the 3DGS convention).
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions};
/// use latentam_core::optim::{GaussianLearningRates, GaussianOptimizer};
/// use latentam_core::splat::GaussianBuffers;
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let params = GaussianBuffers::new(&ctx, "gaussians", 1000)?;
/// let grads = GaussianBuffers::new(&ctx, "grads", 1000)?;
/// let adam = GaussianOptimizer::new(&ctx, 1000, GaussianLearningRates::default())?;
/// // ... render, evaluate the loss, back-propagate into `grads` ...
/// let mut rec = ctx.recorder()?;
/// adam.record_step(&mut rec, &params, &grads, 1000, None)?;
/// rec.submit()?.wait()?;
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct GaussianOptimizer {
    groups: Vec<AdamGroup>,
}

const FIELDS: [&str; 6] = [
    "means",
    "log_scales",
    "quats",
    "colors",
    "opacity",
    "queries",
];

impl GaussianOptimizer {
    /// Zero state for `capacity` Gaussians.
    pub fn new(ctx: &Context, capacity: u32, lrs: GaussianLearningRates) -> Result<Self> {
        let groups = FIELDS
            .iter()
            .zip(FIELD_WIDTHS)
            .zip(lrs.in_field_order())
            .map(|((name, w), lr)| {
                AdamGroup::new(
                    ctx,
                    &format!("gaussians/{name}"),
                    capacity,
                    w as u32,
                    AdamHyper::new(lr, 1e-15),
                )
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(GaussianOptimizer { groups })
    }

    /// Records one step of the first `rows` Gaussians from `grads`; with a
    /// `mask` (one u32 per Gaussian) only Gaussians seen by the batch move.
    pub fn record_step<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        params: &'a GaussianBuffers,
        grads: &'a GaussianBuffers,
        rows: u32,
        mask: Option<&'a Buffer>,
    ) -> Result<()> {
        for ((g, p), d) in self.groups.iter().zip(params.fields()).zip(grads.fields()) {
            g.record_step(rec, p, d, rows, mask)?;
        }
        Ok(())
    }

    /// Every per-Gaussian state buffer with its bytes per row, to be moved
    /// along with the parameters when the window pages.
    pub fn state(&self) -> Vec<(&Buffer, u64)> {
        self.groups.iter().flat_map(|g| g.state()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::splat::HostGaussians;
    use latentam_gpu::testing::with_context;

    #[test]
    fn each_field_moves_at_its_own_rate() {
        with_context(|ctx| {
            let n = 3u32;
            let params = GaussianBuffers::new(ctx, "test/params", n as u64).unwrap();
            let grads = GaussianBuffers::new(ctx, "test/grads", n as u64).unwrap();
            let zeros = HostGaussians::zeros(n as usize);
            params.upload(ctx, 0, &zeros).unwrap();
            let mut ones = HostGaussians::zeros(n as usize);
            ones.means.iter_mut().for_each(|v| *v = [1.0; 3]);
            ones.log_scales.iter_mut().for_each(|v| *v = [1.0; 3]);
            ones.quats.iter_mut().for_each(|v| *v = [1.0; 4]);
            ones.colors.iter_mut().for_each(|v| *v = [1.0; 3]);
            ones.opacity_logits.iter_mut().for_each(|v| *v = 1.0);
            ones.queries.iter_mut().for_each(|v| *v = [1.0; 32]);
            grads.upload(ctx, 0, &ones).unwrap();
            let lrs = GaussianLearningRates::default();
            let opt = GaussianOptimizer::new(ctx, n, lrs).unwrap();
            assert_eq!(opt.state().len(), 18);
            let mut rec = ctx.recorder().unwrap();
            opt.record_step(&mut rec, &params, &grads, n, None).unwrap();
            rec.submit().unwrap().wait().unwrap();
            let out = params.download(ctx, n as u64).unwrap();
            // Adam's first step moves every element by −lr·sign(g).
            // (1 − β₂ in f32 is off by ~1e-5 relative, hence the tolerance.)
            let close = |a: f32, b: f32| (a - b).abs() <= 1e-4 * b.abs();
            assert!(close(out.means[2][1], -lrs.means));
            assert!(close(out.log_scales[0][0], -lrs.log_scales));
            assert!(close(out.quats[1][3], -lrs.quats));
            assert!(close(out.colors[0][2], -lrs.colors));
            assert!(close(out.opacity_logits[1], -lrs.opacity));
            assert!(close(out.queries[2][31], -lrs.queries));
        });
    }
}
