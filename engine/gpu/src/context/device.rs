//! The device and everything tied to its lifetime: queues with their
//! timeline semaphores, the allocator, deferred destruction, pipelines.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use ash::vk;

use super::{DeviceInfo, ValidationLog};
use crate::counters::CallCounters;
use crate::memory::MemoryAccounting;
use crate::objects::ObjectCounts;
use crate::pipeline::PipelineCache;
use crate::profiler::Profiler;
use crate::retire::{RetireQueue, Retired};
use crate::work::WorkCounters;

/// One queue and the timeline semaphore its submissions signal.
pub(crate) struct Queue {
    pub family: u32,
    /// Shared by the two `Queue`s when the transfer path rehearses on the
    /// compute queue itself (`TransferQueue::SameFamily` with one queue in
    /// the family): one lock, since Vulkan queues are externally
    /// synchronised.
    pub queue: Arc<Mutex<vk::Queue>>,
    pub timeline: vk::Semaphore,
    /// Last value handed to a submission.
    pub submitted: AtomicU64,
    /// Last value handed to a submission the other queue's later batches
    /// wait for: all but detached ones (see `Recorder::detach`).
    pub attached: AtomicU64,
    /// Valid bits of this family's timestamps (0: none).
    pub timestamp_bits: u32,
}

/// The device and everything tied to its lifetime. Held by `Arc` in every GPU
/// object, so it is destroyed last.
pub(crate) struct Device {
    /// Keeps the Vulkan loader loaded until the instance is destroyed.
    pub(super) _entry: ash::Entry,
    pub instance: ash::Instance,
    pub debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    pub validation_log: Arc<ValidationLog>,
    pub raw: ash::Device,
    pub info: DeviceInfo,
    pub compute: Queue,
    pub transfer: Option<Queue>,
    pub allocator: Mutex<Option<gpu_allocator::vulkan::Allocator>>,
    pub memory: MemoryAccounting,
    pub retired: RetireQueue,
    pub objects: ObjectCounts,
    pub pipelines: PipelineCache,
    /// The driver's cache of compiled pipelines (null: none), saved to
    /// `info.pipeline_cache_file` when the device is destroyed.
    pub pipeline_cache: vk::PipelineCache,
    pub profiler: Option<Mutex<Profiler>>,
    /// Query pools can be reset from the host (Vulkan 1.2 `hostQueryReset`).
    pub host_query_reset: bool,
    /// Submissions, host waits and dispatches so far.
    pub(crate) calls: CallCounters,
    /// Work recorded so far, by kernel (`Context::gpu_work`).
    pub(crate) work: WorkCounters,
    /// When the device was opened, and how long after that every kernel
    /// a caller warmed up was ready (see `Context::warm_up_only`).
    pub(crate) opened: std::time::Instant,
    pub(crate) ready_after: Mutex<Option<std::time::Duration>>,
    /// What each kernel built by a warm-up cost (`Context::kernel_build_times`).
    pub(crate) build_times: Mutex<Vec<crate::KernelBuildTime>>,
}

impl Device {
    /// Families that buffers must be shareable between.
    pub fn queue_families(&self) -> Vec<u32> {
        let mut f = vec![self.compute.family];
        if let Some(t) = self
            .transfer
            .as_ref()
            .filter(|t| t.family != self.compute.family)
        {
            f.push(t.family);
        }
        f
    }

    /// The transfer queue when asked for and present, else the compute queue.
    pub fn queue(&self, transfer: bool) -> &Queue {
        match (&self.transfer, transfer) {
            (Some(t), true) => t,
            _ => &self.compute,
        }
    }

    /// Current completed values of (compute, transfer) timelines.
    pub fn completed(&self) -> (u64, u64) {
        // SAFETY: the semaphores live as long as `self`.
        let c = unsafe { self.raw.get_semaphore_counter_value(self.compute.timeline) }.unwrap_or(0);
        let t = match &self.transfer {
            // SAFETY: as above.
            Some(q) => unsafe { self.raw.get_semaphore_counter_value(q.timeline) }.unwrap_or(0),
            None => 0,
        };
        (c, t)
    }

    /// Values of the latest submissions on (compute, transfer).
    pub fn submitted(&self) -> (u64, u64) {
        (
            self.compute.submitted.load(Ordering::SeqCst),
            self.transfer
                .as_ref()
                .map(|q| q.submitted.load(Ordering::SeqCst))
                .unwrap_or(0),
        )
    }

    /// Queue an object for destruction once the GPU is done with everything
    /// submitted so far.
    pub fn retire(&self, obj: Retired) {
        self.retired.push(self.submitted(), obj);
        self.collect();
    }

    /// Destroy retired objects whose submissions have completed.
    pub fn collect(&self) {
        let done = self.completed();
        let ready = self.retired.take_ready(done);
        if !ready.is_empty() {
            self.destroy(ready);
        }
    }

    pub fn destroy(&self, objs: Vec<Retired>) {
        let mut alloc = self.allocator.lock().unwrap_or_else(|p| p.into_inner());
        for o in objs {
            o.destroy(&self.raw, alloc.as_mut(), &self.memory, &self.objects);
        }
    }
}

impl Device {
    /// Writes the driver's compiled pipelines to the cache file (a failure
    /// only warns: the next process compiles again).
    fn save_pipeline_cache(&self) {
        let Some(path) = &self.info.pipeline_cache_file else {
            return;
        };
        if self.pipeline_cache == vk::PipelineCache::null() {
            return;
        }
        // SAFETY: the cache belongs to this device and is not in use.
        let data = unsafe { self.raw.get_pipeline_cache_data(self.pipeline_cache) };
        match data {
            Ok(d) if !d.is_empty() => {
                if let Err(e) = crate::pipeline_cache_file::save(path, &d) {
                    log::warn!("{}: pipeline cache not saved: {e}", path.display());
                }
            }
            Ok(_) => {}
            Err(e) => log::warn!("vkGetPipelineCacheData: {e}"),
        }
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: nothing else references the device any more (this is the
        // last `Arc`); wait for the GPU, then destroy children before parents.
        unsafe {
            let _ = self.raw.device_wait_idle();
            let all = self.retired.take_all();
            self.destroy(all);
            self.save_pipeline_cache();
            self.pipelines.destroy_all(&self.raw);
            if self.pipeline_cache != vk::PipelineCache::null() {
                self.raw.destroy_pipeline_cache(self.pipeline_cache, None);
            }
            // The allocator frees its memory blocks on drop.
            drop(
                self.allocator
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .take(),
            );
            self.raw.destroy_semaphore(self.compute.timeline, None);
            if let Some(t) = &self.transfer {
                self.raw.destroy_semaphore(t.timeline, None);
            }
            self.raw.destroy_device(None);
            if let Some((du, m)) = self.debug.take() {
                du.destroy_debug_utils_messenger(m, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}
