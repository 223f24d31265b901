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
mod kernel_build_time;
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
mod warm_up;
mod work;

pub use buffer::{Buffer, Readback};
pub use context::{
    Context, ContextOptions, DeviceInfo, FloatAtomics, TransferQueue, Validation, ValidationChecks,
    ValidationLog,
};
pub use counters::GpuCalls;
pub use host_spans::HostSpan;
pub use host_time::{ClockSync, HostSample, HOST_WAIT};
pub use kernel_build_time::KernelBuildTime;
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

    /// Whether timestamps are being recorded.
    pub fn profiling(&self) -> bool {
        self.dev.profiler.is_some()
    }
}
