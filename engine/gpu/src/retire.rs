//! Deferred destruction: a GPU object dropped by its owner is destroyed only
//! once every submission made before the drop has completed.

use std::sync::Mutex;

use ash::vk;

use super::memory::MemoryAccounting;
use super::objects::{ObjectCounts, ObjectKind};

/// A Vulkan object waiting for the GPU to finish with it.
pub(crate) enum Retired {
    Buffer {
        buffer: vk::Buffer,
        allocation: gpu_allocator::vulkan::Allocation,
        category: String,
        bytes: u64,
    },
    CommandPool(vk::CommandPool),
    DescriptorPool(vk::DescriptorPool),
    QueryPool(vk::QueryPool),
}

impl Retired {
    pub fn destroy(
        self,
        dev: &ash::Device,
        alloc: Option<&mut gpu_allocator::vulkan::Allocator>,
        memory: &MemoryAccounting,
        objects: &ObjectCounts,
    ) {
        // SAFETY: the retire queue only hands out objects whose last use has
        // completed, and each object is retired exactly once by its owner.
        unsafe {
            match self {
                Retired::Buffer {
                    buffer,
                    allocation,
                    category,
                    bytes,
                } => {
                    dev.destroy_buffer(buffer, None);
                    if let Some(a) = alloc {
                        if let Err(e) = a.free(allocation) {
                            log::error!("freeing GPU memory failed: {e}");
                        }
                    }
                    memory.release(&category, bytes);
                    objects.destroyed(ObjectKind::Buffer);
                }
                Retired::CommandPool(p) => {
                    dev.destroy_command_pool(p, None);
                    objects.destroyed(ObjectKind::CommandPool);
                }
                Retired::DescriptorPool(p) => {
                    dev.destroy_descriptor_pool(p, None);
                    objects.destroyed(ObjectKind::DescriptorPool);
                }
                Retired::QueryPool(p) => {
                    dev.destroy_query_pool(p, None);
                    objects.destroyed(ObjectKind::QueryPool);
                }
            }
        }
    }
}

/// Objects tagged with the (compute, transfer) timeline values that must be
/// reached before they can be destroyed.
#[derive(Default)]
pub(crate) struct RetireQueue {
    items: Mutex<Vec<((u64, u64), Retired)>>,
}

impl RetireQueue {
    pub fn push(&self, after: (u64, u64), obj: Retired) {
        self.items
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push((after, obj));
    }

    pub fn take_ready(&self, done: (u64, u64)) -> Vec<Retired> {
        let mut items = self.items.lock().unwrap_or_else(|p| p.into_inner());
        let mut ready = Vec::new();
        let mut i = 0;
        while i < items.len() {
            let (c, t) = items[i].0;
            if c <= done.0 && t <= done.1 {
                ready.push(items.swap_remove(i).1);
            } else {
                i += 1;
            }
        }
        ready
    }

    /// Objects waiting.
    pub fn len(&self) -> usize {
        self.items.lock().unwrap_or_else(|p| p.into_inner()).len()
    }

    pub fn take_all(&self) -> Vec<Retired> {
        self.items
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .drain(..)
            .map(|(_, o)| o)
            .collect()
    }
}
