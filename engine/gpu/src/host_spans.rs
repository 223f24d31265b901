//! Host time beside GPU time: spans of CPU work (a stage of a keyframe, a
//! wait for the GPU) recorded into the profiler, and the offset that puts
//! them on the device's timestamp clock, so a trace shows where the host
//! works and where it waits next to what the GPU runs.

use std::time::Instant;

use crate::host_time::{host_ns, ClockSync};
use crate::{Context, Result};

/// A span of host work, recorded into the profiler when dropped (nothing
/// is recorded when profiling is off).
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context) {
/// {
///     let _span = ctx.host_span("seeding");
///     // ... CPU work ...
/// } // recorded here
/// # }
/// ```
#[must_use = "the span ends when this value is dropped"]
pub struct HostSpan {
    ctx: Option<Context>,
    name: &'static str,
    start: Instant,
}

impl Drop for HostSpan {
    fn drop(&mut self) {
        if let Some(ctx) = &self.ctx {
            ctx.record_host(self.name, self.start, Instant::now());
        }
    }
}

impl Context {
    /// Starts a span of host work named `name`; it ends when the returned
    /// value is dropped. With profiling on it appears in the trace beside
    /// the GPU's commands; otherwise it costs one branch.
    pub fn host_span(&self, name: &'static str) -> HostSpan {
        HostSpan {
            ctx: self.profiling().then(|| self.clone()),
            name,
            start: Instant::now(),
        }
    }

    /// Records host time from `start` to `end` when profiling.
    pub(crate) fn record_host(&self, name: &'static str, start: Instant, end: Instant) {
        if let Some(p) = &self.dev.profiler {
            p.lock()
                .unwrap_or_else(|e| e.into_inner())
                .record_host(name, start, end);
        }
    }

    /// Measures how host time maps onto the device's timestamps: one
    /// timestamp written by an otherwise empty submission, between the
    /// host times before its submission and after its wait. Does nothing
    /// without profiling or timestamps. Called when the context opens and
    /// again once the last measurement is older than
    /// `RECALIBRATE_AFTER_NS`.
    pub(crate) fn calibrate_host_clock(&self) -> Result<()> {
        if !self.profiling() {
            return Ok(());
        }
        let before = Instant::now();
        let mut rec = self.recorder()?;
        rec.start_span();
        rec.for_calibration();
        let span = rec.submit()?.wait_span()?;
        let after = Instant::now();
        if let (Some(span), Some(p)) = (span, &self.dev.profiler) {
            let (t0, t1) = (host_ns(before), host_ns(after));
            let mut p = p.lock().unwrap_or_else(|e| e.into_inner());
            p.set_clock(ClockSync {
                host_ns: 0.5 * (t0 + t1),
                host_to_device_ns: span.start_ns - 0.5 * (t0 + t1),
                error_ns: 0.5 * (t1 - t0),
            });
        }
        Ok(())
    }
}
