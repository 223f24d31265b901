//! Host time as the profiler keeps it: spans of host work on a process-wide
//! clock, and how that clock maps onto the device's timestamps.

use std::sync::OnceLock;
use std::time::Instant;

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

/// How long a clock calibration is trusted: the host's clock and the
/// device's may run at rates apart by hundreds of ppm (the host's is
/// slewed, a driver's may not be), a few hundred microseconds a second,
/// so a profiling context calibrates again at its first wait after this.
pub(crate) const RECALIBRATE_AFTER_NS: f64 = 100e6;

/// How host time maps onto the device's timestamp clock: device ns =
/// host ns + `host_to_device_ns`, within `error_ns` (half the round trip
/// of the calibrating submission).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ClockSync {
    /// When it was measured, host ns.
    pub host_ns: f64,
    /// Added to a host time to get the device time.
    pub host_to_device_ns: f64,
    /// Bound on the error of that offset.
    pub error_ns: f64,
}

/// The current thread's name for a trace track.
pub(crate) fn thread_name() -> String {
    let t = std::thread::current();
    t.name()
        .map(str::to_string)
        .unwrap_or_else(|| format!("{:?}", t.id()))
}
