//! Counts of what the host asks of the GPU: submissions, host waits,
//! dispatches and the bytes that cross the host link. Each wait is a CPU–GPU round trip (20–100 µs on a discrete
//! GPU, plus the GPU idling while the host prepares the next batch), so a
//! latency-critical caller wants them few and counted.

use std::ops::Sub;
use std::sync::atomic::{AtomicU64, Ordering};

/// A snapshot of [`crate::Context::gpu_calls`]; subtract two to count
/// what happened between them.
///
/// ```
/// # use latentam_gpu::*;
/// let ctx = Context::new(ContextOptions::default())?;
/// let buf = Buffer::device(&ctx, "example/buf", 256)?;
/// let before = ctx.gpu_calls();
/// ctx.upload(&buf, 0, &[1u32; 64])?;
/// let used = ctx.gpu_calls() - before;
/// assert_eq!((used.submissions, used.host_waits, used.dispatches), (1, 1, 0));
/// assert_eq!((used.uploaded_bytes, used.downloaded_bytes), (256, 0));
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct GpuCalls {
    /// Command batches submitted to a queue.
    pub submissions: u64,
    /// Times the host blocked until the GPU finished (a submission's wait,
    /// a wait for idle).
    pub host_waits: u64,
    /// Kernel dispatches recorded.
    pub dispatches: u64,
    /// Bytes recorded to be copied from host-visible staging into device
    /// buffers (as [`crate::GpuWork::uploaded_bytes`] counts them).
    pub uploaded_bytes: u64,
    /// Bytes recorded to be copied from device buffers into host-visible
    /// staging.
    pub downloaded_bytes: u64,
}

impl Sub for GpuCalls {
    type Output = GpuCalls;

    fn sub(self, earlier: GpuCalls) -> GpuCalls {
        GpuCalls {
            submissions: self.submissions.saturating_sub(earlier.submissions),
            host_waits: self.host_waits.saturating_sub(earlier.host_waits),
            dispatches: self.dispatches.saturating_sub(earlier.dispatches),
            uploaded_bytes: self.uploaded_bytes.saturating_sub(earlier.uploaded_bytes),
            downloaded_bytes: self
                .downloaded_bytes
                .saturating_sub(earlier.downloaded_bytes),
        }
    }
}

impl std::ops::Add for GpuCalls {
    type Output = GpuCalls;

    fn add(self, other: GpuCalls) -> GpuCalls {
        GpuCalls {
            submissions: self.submissions + other.submissions,
            host_waits: self.host_waits + other.host_waits,
            dispatches: self.dispatches + other.dispatches,
            uploaded_bytes: self.uploaded_bytes + other.uploaded_bytes,
            downloaded_bytes: self.downloaded_bytes + other.downloaded_bytes,
        }
    }
}

/// The device's running counts.
#[derive(Default)]
pub(crate) struct CallCounters {
    submissions: AtomicU64,
    host_waits: AtomicU64,
    dispatches: AtomicU64,
    uploaded_bytes: AtomicU64,
    downloaded_bytes: AtomicU64,
}

impl CallCounters {
    pub fn submitted(&self) {
        self.submissions.fetch_add(1, Ordering::Relaxed);
    }

    pub fn waited(&self) {
        self.host_waits.fetch_add(1, Ordering::Relaxed);
    }

    pub fn dispatched(&self) {
        self.dispatches.fetch_add(1, Ordering::Relaxed);
    }

    pub fn uploaded(&self, bytes: u64) {
        self.uploaded_bytes.fetch_add(bytes, Ordering::Relaxed);
    }

    pub fn downloaded(&self, bytes: u64) {
        self.downloaded_bytes.fetch_add(bytes, Ordering::Relaxed);
    }

    pub fn snapshot(&self) -> GpuCalls {
        GpuCalls {
            submissions: self.submissions.load(Ordering::Relaxed),
            host_waits: self.host_waits.load(Ordering::Relaxed),
            dispatches: self.dispatches.load(Ordering::Relaxed),
            uploaded_bytes: self.uploaded_bytes.load(Ordering::Relaxed),
            downloaded_bytes: self.downloaded_bytes.load(Ordering::Relaxed),
        }
    }
}
