//! A submitted batch: waiting on it, and reading its kernels' timestamps
//! into the profiler.

use super::*;
use crate::host_time::{HOST_WAIT, RECALIBRATE_AFTER_NS};

/// A submitted batch of work.
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context, buf: &latentam_gpu::Buffer) -> latentam_gpu::Result<()> {
/// let mut rec = ctx.recorder()?;
/// rec.fill_u32(buf, 0);
/// let submission = rec.submit()?;
/// // ... CPU work while the GPU runs ...
/// submission.wait()?;
/// # Ok(())
/// # }
/// ```
#[must_use = "a submission should be waited on (or its sync point used)"]
pub struct Submission {
    pub(super) dev: Arc<Device>,
    pub(super) point: SyncPoint,
    pub(super) queries: Vec<QueryBlock>,
    pub(super) labels: Vec<(&'static str, u32, u32)>,
    pub(super) span: Option<(u32, u32)>,
    /// A clock calibration's own submission: its wait is not counted or
    /// traced and triggers no further calibration.
    pub(super) calibration: bool,
}

/// When a timed batch ran on the GPU ([`Recorder::start_span`]), in
/// nanoseconds of the device's timestamp clock.
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context, buf: &latentam_gpu::Buffer) -> latentam_gpu::Result<()> {
/// let mut rec = ctx.recorder()?;
/// rec.start_span();
/// rec.fill_u32(buf, 7);
/// if let Some(span) = rec.submit()?.wait_span()? {
///     println!("the batch took {:.3} ms on the GPU", span.ms());
/// }
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpuSpan {
    /// First command started.
    pub start_ns: f64,
    /// Last command finished.
    pub end_ns: f64,
}

impl GpuSpan {
    /// Duration in milliseconds.
    pub fn ms(&self) -> f64 {
        (self.end_ns - self.start_ns).max(0.0) * 1e-6
    }

    /// Milliseconds of this span that ran before `other` began.
    pub fn ms_before(&self, other: &GpuSpan) -> f64 {
        (self.end_ns.min(other.start_ns) - self.start_ns).max(0.0) * 1e-6
    }

    /// Milliseconds during which both spans ran.
    pub fn overlap_ms(&self, other: &GpuSpan) -> f64 {
        (self.end_ns.min(other.end_ns) - self.start_ns.max(other.start_ns)).max(0.0) * 1e-6
    }
}

impl Submission {
    /// Where this submission ends on its queue's timeline.
    pub fn sync_point(&self) -> SyncPoint {
        self.point
    }

    /// Whether the GPU has finished it.
    pub fn is_done(&self) -> bool {
        let done = self.dev.completed();
        let reached = if self.point.transfer { done.1 } else { done.0 };
        reached >= self.point.value
    }

    /// Blocks until the GPU has finished, then hands the batch's timestamps
    /// to the profiler.
    pub fn wait(self) -> Result<()> {
        self.wait_span().map(|_| ())
    }

    /// [`Submission::wait_span`] for a batch the GPU has already finished
    /// (a later batch that waited for it on the GPU was waited for):
    /// returns its span and hands its timestamps to the profiler without a
    /// host wait. Waits, counted, if it is not finished after all.
    pub fn finished_span(mut self) -> Result<Option<GpuSpan>> {
        if !self.is_done() {
            return self.wait_span();
        }
        // A wait that is already satisfied returns at once; it is made
        // anyway (not counted: nothing blocks) because a host wait, not a
        // read of the counter, is what makes the batch's writes visible
        // to host reads.
        self.wait_semaphore(0)?;
        let span = self.collect_timestamps();
        self.dev.collect();
        Ok(span)
    }

    /// [`Submission::wait`], returning when the batch ran if it was timed
    /// ([`Recorder::start_span`]) and the queue has timestamps.
    pub fn wait_span(mut self) -> Result<Option<GpuSpan>> {
        if !self.calibration {
            self.dev.calls.waited();
        }
        let waiting = std::time::Instant::now();
        self.wait_semaphore(u64::MAX)?;
        let mut recalibrate = false;
        if let (Some(p), false) = (&self.dev.profiler, self.calibration) {
            let mut p = p.lock().unwrap_or_else(|e| e.into_inner());
            let end_ns = p.record_host(HOST_WAIT, waiting, std::time::Instant::now());
            recalibrate = p.clock_age_ns(end_ns) > RECALIBRATE_AFTER_NS;
        }
        let span = self.collect_timestamps();
        if recalibrate {
            Context {
                dev: self.dev.clone(),
            }
            .calibrate_host_clock()?;
        }
        self.dev.collect();
        Ok(span)
    }

    /// Waits up to `timeout_ns` for this batch's point on its queue's
    /// timeline.
    fn wait_semaphore(&self, timeout_ns: u64) -> Result<()> {
        let sems = [self.dev.queue(self.point.transfer).timeline];
        let values = [self.point.value];
        // SAFETY: waiting on our own timeline semaphore.
        unsafe {
            self.dev.raw.wait_semaphores(
                &vk::SemaphoreWaitInfo::default()
                    .semaphores(&sems)
                    .values(&values),
                timeout_ns,
            )
        }
        .vk("vkWaitSemaphores")
    }

    fn collect_timestamps(&mut self) -> Option<GpuSpan> {
        if self.labels.is_empty() && self.span.is_none() {
            return None;
        }
        let period = self.dev.info.timestamp_period_ns.unwrap_or(1.0);
        let bits = self.dev.queue(self.point.transfer).timestamp_bits;
        let mask = if bits >= 64 {
            u64::MAX
        } else {
            (1u64 << bits) - 1
        };
        let mut values: Vec<Vec<u64>> = Vec::new();
        for q in &self.queries {
            let mut v = vec![0u64; q.used as usize];
            // SAFETY: the submission completed, so every written query is
            // available; we read only the used ones.
            let r = unsafe {
                self.dev.raw.get_query_pool_results(
                    q.pool,
                    0,
                    &mut v,
                    vk::QueryResultFlags::TYPE_64,
                )
            };
            if r.is_err() {
                return None;
            }
            values.push(v);
        }
        let get = |i: u32| {
            let b = (i / QUERIES_PER_POOL) as usize;
            values[b][(i % QUERIES_PER_POOL) as usize] & mask
        };
        let span = self.span.map(|(s, e)| GpuSpan {
            start_ns: get(s) as f64 * period,
            end_ns: get(e) as f64 * period,
        });
        let Some(profiler) = &self.dev.profiler else {
            return span;
        };
        let mut p = profiler.lock().unwrap_or_else(|e| e.into_inner());
        let queue = if self.point.transfer {
            "transfer"
        } else {
            "compute"
        };
        for (name, s, e) in &self.labels {
            let start = get(*s) as f64 * period;
            let end = get(*e) as f64 * period;
            p.record(name, queue, start, (end - start).max(0.0));
        }
        span
    }
}

impl Drop for Submission {
    fn drop(&mut self) {
        for q in self.queries.drain(..) {
            self.dev.retire(Retired::QueryPool(q.pool));
        }
    }
}
