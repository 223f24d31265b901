//! Stage II (paper Alg. 1, line 6): further steps on W and D from the
//! region queries Stage I pooled, submitted so that paging can run beside
//! them on the transfer queue.

use super::Trainer;
use crate::latent::LatentHead;
use crate::loss::FeatureLoss;
use latentam_base::Result;
use latentam_gpu::{Context, GpuSpan, Readback, Submission};

impl Trainer {
    /// Stage II: `iterations` steps on W and D from the region queries of
    /// the last Stage I; returns the feature loss of the last step (before
    /// its update). Nothing to do when the batch had no regions.
    pub fn stage_two(
        &self,
        ctx: &Context,
        head: Option<&LatentHead>,
        iterations: u32,
    ) -> Result<f64> {
        Ok(self.submit_stage_two(ctx, head, iterations)?.finish()?.0)
    }

    /// [`Trainer::stage_two`] without waiting: the work is submitted (and
    /// timed) on the compute queue, so paging can run beside it.
    pub fn submit_stage_two(
        &self,
        ctx: &Context,
        head: Option<&LatentHead>,
        iterations: u32,
    ) -> Result<StageTwoRun> {
        let n = self.regions;
        let Some(head) = head else {
            return Ok(StageTwoRun(None));
        };
        if n == 0 || iterations == 0 {
            return Ok(StageTwoRun(None));
        }
        let region_targets = &self.region_targets;
        let mut rec = ctx.recorder()?;
        // Stage II reads and writes the latent head and the pooled
        // features only, never the window that a paging batch submitted
        // just before it moves: it runs beside that batch.
        rec.overlap_other_queue();
        rec.start_span();
        let mut last = None;
        for i in 0..iterations {
            head.record_step(
                &mut rec,
                self.pooling.pooled(),
                region_targets,
                &self.row_weights,
                n,
                false,
            )?;
            if i + 1 == iterations {
                last = Some(head.record_loss_readback(&mut rec, n)?.0);
            }
        }
        let submission = rec.submit()?;
        Ok(StageTwoRun(Some((
            submission,
            last.expect("at least one iteration"),
        ))))
    }
}

/// A submitted Stage II.
///
/// ```no_run
/// # use latentam_gpu::Context; use latentam_core::{latent::LatentHead, mapper::Trainer};
/// # fn f(ctx: &Context, trainer: &Trainer, head: &LatentHead) -> latentam_core::Result<()> {
/// let run = trainer.submit_stage_two(ctx, Some(head), 10)?;
/// // ... page the window on the transfer queue meanwhile ...
/// let (feature_loss, span) = run.finish()?;
/// if let Some(span) = span {
///     println!("Stage II: loss {feature_loss:.4} in {:.2} ms", span.ms());
/// }
/// # Ok(())
/// # }
/// ```
#[must_use = "Stage II must be finished"]
pub struct StageTwoRun(Option<(Submission, Readback)>);

impl StageTwoRun {
    /// Waits; returns the feature loss of the last step and when the work
    /// ran on the GPU (when it could be timed).
    pub fn finish(self) -> Result<(f64, Option<GpuSpan>)> {
        self.finish_with(Submission::wait_span)
    }

    /// [`StageTwoRun::finish`] once a later batch on the compute queue was
    /// waited for, which Stage II ran before: no host wait (one, counted,
    /// if it is not finished after all).
    pub fn finish_after_later_wait(self) -> Result<(f64, Option<GpuSpan>)> {
        self.finish_with(Submission::finished_span)
    }

    fn finish_with(
        self,
        wait: impl FnOnce(Submission) -> Result<Option<GpuSpan>>,
    ) -> Result<(f64, Option<GpuSpan>)> {
        match self.0 {
            None => Ok((0.0, None)),
            Some((submission, readback)) => {
                let span = wait(submission)?;
                Ok((FeatureLoss::sum(&readback)?, span))
            }
        }
    }
}
