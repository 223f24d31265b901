//! Host time beside GPU time: spans of CPU work (a stage of a keyframe, a
//! wait for the GPU) recorded into the profiler, and the offset that puts
//! them on the device's timestamp clock, so a trace shows where the host
//! works and where it waits next to what the GPU runs.

use std::sync::OnceLock;
use std::time::Instant;

use crate::{Context, Result};

/// The host clock's zero for the process: host samples are nanoseconds
/// since this instant.
fn anchor() -> Instant {
    static ANCHOR: OnceLock<Instant> = OnceLock::new();
    *ANCHOR.get_or_init(Instant::now)
}

/// `t` in nanoseconds since the process's host clock zero.
pub(crate) fn host_ns(t: Instant) -> f64 {
    t.saturating_duration_since(anchor()).as_nanos() as f64
}

/// One stretch of host time.
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context) {
/// let waited_ms: f64 = ctx
///     .profiler_snapshot()
///     .host_samples()
///     .iter()
///     .filter(|s| s.name == latentam_gpu::HOST_WAIT)
///     .map(|s| s.duration_ns * 1e-6)
///     .sum();
/// println!("the host waited {waited_ms:.1} ms for the GPU");
/// # }
/// ```
#[derive(Clone, Debug, serde::Serialize)]
pub struct HostSample {
    /// What the host did ([`HOST_WAIT`] for a wait on a submission).
    pub name: &'static str,
    /// The thread's name (or its id when it has none).
    pub thread: String,
    /// Start on the host clock, nanoseconds since the process's first
    /// span.
    pub start_ns: f64,
    /// Duration in nanoseconds.
    pub duration_ns: f64,
}

/// The name of the host spans that wait on a submission.
pub const HOST_WAIT: &str = "wait for GPU";

/// How host time maps onto the device's timestamp clock: device ns =
/// host ns + `host_to_device_ns`, within `error_ns` (half the round trip
/// of the calibrating submission).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ClockSync {
    /// Added to a host time to get the device time.
    pub host_to_device_ns: f64,
    /// Bound on the error of that offset.
    pub error_ns: f64,
}

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

/// The current thread's name for a trace track.
pub(crate) fn thread_name() -> String {
    let t = std::thread::current();
    t.name()
        .map(str::to_string)
        .unwrap_or_else(|| format!("{:?}", t.id()))
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
            let start_ns = host_ns(start);
            p.lock()
                .unwrap_or_else(|e| e.into_inner())
                .record_host(HostSample {
                    name,
                    thread: thread_name(),
                    start_ns,
                    duration_ns: (host_ns(end) - start_ns).max(0.0),
                });
        }
    }

    /// Measures how host time maps onto the device's timestamps: one
    /// timestamp written by an otherwise empty submission, between the
    /// host times before its submission and after its wait. Does nothing
    /// without profiling or timestamps.
    pub(crate) fn calibrate_host_clock(&self) -> Result<()> {
        if !self.profiling() {
            return Ok(());
        }
        let before = Instant::now();
        let mut rec = self.recorder()?;
        rec.start_span();
        let span = rec.submit()?.wait_span()?;
        let after = Instant::now();
        if let (Some(span), Some(p)) = (span, &self.dev.profiler) {
            let (t0, t1) = (host_ns(before), host_ns(after));
            let mut p = p.lock().unwrap_or_else(|e| e.into_inner());
            p.set_clock(ClockSync {
                host_to_device_ns: span.start_ns - 0.5 * (t0 + t1),
                error_ns: 0.5 * (t1 - t0),
            });
            // The calibration is no work of the caller's.
            p.clear();
        }
        Ok(())
    }
}
