//! # latentam-gpu
//!
//! latentam's Vulkan layer: device selection, memory, buffers with explicit staging,
//! pipelines, command recording and profiling.
//!
//! Ownership rule: every Vulkan object belongs to exactly one Rust value and
//! is destroyed when that value drops, deferred until the GPU has finished
//! every submission made before the drop (see `retire.rs`). The device itself
//! goes last, when the final [`Context`] clone and GPU object are gone.

#![warn(missing_docs)]

mod buffer;
mod context;
mod counters;
#[cfg(test)]
mod device_limits_tests;
mod host_spans;
mod host_time;
mod memory;
mod objects;
pub mod ops;
mod pipeline;
mod pipeline_cache_file;
mod profiler;
mod recorder;
mod retire;
#[cfg(any(test, feature = "testing"))]
#[doc(hidden)]
pub mod testing;
#[cfg(test)]
mod tests;
mod work;

pub use buffer::{Buffer, Readback};
pub use context::{
    Context, ContextOptions, DeviceInfo, FloatAtomics, TransferQueue, Validation, ValidationChecks,
    ValidationLog,
};
pub use counters::GpuCalls;
pub use host_spans::HostSpan;
pub use host_time::{ClockSync, HostSample, HOST_WAIT};
pub use latentam_base::{Error, Result};
pub use memory::{ByteCount, MemoryReport};
pub use objects::LiveObjects;
pub use profiler::{KernelStats, Profiler, Sample, DEFAULT_TRACE_SAMPLES};
pub use recorder::{GpuSpan, QueueKind, Recorder, Submission, SyncPoint};
pub use work::{Floor, GpuModel, GpuWork, KernelWork};

impl Context {
    /// Bytes allocated, per category and in total, with peaks.
    pub fn memory_report(&self) -> MemoryReport {
        self.dev.memory.report()
    }

    /// Sets (or clears) the GPU memory budget; later allocations that would
    /// exceed it fail with [`crate::Error::OutOfMemory`].
    pub fn set_memory_budget(&self, bytes: Option<u64>) {
        self.dev.memory.set_budget(bytes)
    }

    /// Vulkan objects alive now (after destroying those the GPU is done
    /// with): equal counts before and after a piece of work mean it leaked
    /// nothing.
    pub fn live_objects(&self) -> LiveObjects {
        self.dev.collect();
        self.dev
            .objects
            .snapshot(self.dev.pipelines.len(), self.dev.retired.len())
    }

    /// A copy of the profiler's samples (empty unless profiling is on).
    pub fn profiler_snapshot(&self) -> Profiler {
        match &self.dev.profiler {
            Some(p) => p.lock().unwrap_or_else(|e| e.into_inner()).clone(),
            None => Profiler::default(),
        }
    }

    /// Clears the profiler's samples.
    pub fn profiler_reset(&self) {
        if let Some(p) = &self.dev.profiler {
            p.lock().unwrap_or_else(|e| e.into_inner()).clear();
        }
    }

    /// Creates the pipeline of every kernel this device can run
    /// ([`DeviceInfo::can_run`]: not those needing features it lacks). lavapipe
    /// compiles a pipeline on first use; call this before timing anything.
    /// Returns the number of pipelines ready.
    pub fn warm_up(&self) -> crate::Result<usize> {
        self.warm_up_only(|_| true)
    }

    /// Whether the driver builds `kernel`'s pipeline (building it now if it
    /// was not yet): `Ok(false)` when its compiler rejects it
    /// ([`Error::KernelBuild`]), remembered so that asking again costs
    /// nothing. For a caller with an alternative variant to fall back on;
    /// other errors (a lost device, exhausted memory) are returned.
    pub fn kernel_builds(&self, kernel: &'static latentam_shaders::Kernel) -> crate::Result<bool> {
        let dev = &self.dev;
        dev.pipelines.builds(&dev.raw, dev.pipeline_cache, kernel)
    }

    /// The kernels the driver failed to build so far, with its results
    /// (see [`Context::kernel_builds`]).
    pub fn kernel_build_failures(&self) -> Vec<(&'static str, ash::vk::Result)> {
        self.dev.pipelines.failures()
    }

    /// [`Context::warm_up`] for the kernels `keep` accepts: a client that
    /// knows which variants it dispatches on this device (see
    /// `latentam_core::mapper::warm_up`) spares the time of the others, which
    /// every process pays even when the driver caches compiled pipelines.
    pub fn warm_up_only(
        &self,
        keep: impl Fn(&latentam_shaders::Kernel) -> bool,
    ) -> crate::Result<usize> {
        let mut n = 0;
        for k in latentam_shaders::ALL {
            if !keep(k) || !self.info().can_run(k) {
                continue;
            }
            self.dev
                .pipelines
                .get(&self.dev.raw, self.dev.pipeline_cache, k)?;
            n += 1;
        }
        *self
            .dev
            .ready_after
            .lock()
            .unwrap_or_else(|e| e.into_inner()) = Some(self.dev.opened.elapsed());
        Ok(n)
    }

    /// How long after the device was opened the last warm-up
    /// ([`Context::warm_up_only`]) had every kernel ready, ms; `None`
    /// before one. With a warm pipeline cache this is mostly the
    /// driver's start.
    pub fn time_to_ready_ms(&self) -> Option<f64> {
        self.dev
            .ready_after
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .map(|d| d.as_secs_f64() * 1e3)
    }

    /// Whether timestamps are being recorded.
    pub fn profiling(&self) -> bool {
        self.dev.profiler.is_some()
    }
}
