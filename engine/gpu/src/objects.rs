//! Counts of live Vulkan objects, so long runs can prove they leak none:
//! every creation site counts up, every destruction counts down.

use std::sync::atomic::{AtomicI64, Ordering};

/// Kinds of objects the engine creates while running (the device, queues'
/// semaphores and the instance live as long as the context and are not
/// counted).
#[derive(Clone, Copy, Debug)]
pub(crate) enum ObjectKind {
    Buffer,
    CommandPool,
    DescriptorPool,
    QueryPool,
}

#[derive(Default)]
pub(crate) struct ObjectCounts {
    counts: [AtomicI64; 4],
}

impl ObjectCounts {
    pub fn created(&self, kind: ObjectKind) {
        self.counts[kind as usize].fetch_add(1, Ordering::Relaxed);
    }

    pub fn destroyed(&self, kind: ObjectKind) {
        self.counts[kind as usize].fetch_sub(1, Ordering::Relaxed);
    }

    pub fn snapshot(&self, pipelines: usize, awaiting_destruction: usize) -> LiveObjects {
        let c = |k: ObjectKind| self.counts[k as usize].load(Ordering::Relaxed);
        LiveObjects {
            buffers: c(ObjectKind::Buffer),
            command_pools: c(ObjectKind::CommandPool),
            descriptor_pools: c(ObjectKind::DescriptorPool),
            query_pools: c(ObjectKind::QueryPool),
            pipelines: pipelines as i64,
            awaiting_destruction,
        }
    }
}

/// Vulkan objects alive on a context (see
/// [`super::Context::live_objects`]), including those dropped by their
/// owner but waiting for the GPU before destruction.
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context) -> latentam_gpu::Result<()> {
/// let before = ctx.live_objects();
/// drop(ctx.upload_new("example/scratch", &[0u32; 64])?);
/// ctx.wait_idle()?;
/// assert_eq!(ctx.live_objects().buffers, before.buffers);
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct LiveObjects {
    /// Buffers, each with its memory allocation.
    pub buffers: i64,
    /// Command pools (one per recorder).
    pub command_pools: i64,
    /// Descriptor pools.
    pub descriptor_pools: i64,
    /// Timestamp query pools.
    pub query_pools: i64,
    /// Compute pipelines (created once per kernel, kept for the context's
    /// life).
    pub pipelines: i64,
    /// Of the above, objects dropped and waiting for the GPU to finish
    /// with them.
    pub awaiting_destruction: usize,
}
