//! What the selected device offers, as the engine uses it.

use ash::vk;

/// What the selected device offers, as the engine uses it.
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context) {
/// let info = ctx.info();
/// println!("{} ({:?}), subgroups of {}", info.name, info.device_type, info.subgroup_size);
/// let max_floats_per_buffer = info.max_buffer_bytes() / 4;
/// # }
/// ```
#[derive(Clone, Debug)]
pub struct DeviceInfo {
    /// Device name as the driver reports it.
    pub name: String,
    /// Discrete, integrated, CPU, ...
    pub device_type: vk::PhysicalDeviceType,
    /// Driver-reported Vulkan API version.
    pub api_version: u32,
    /// Whether kernels use native float atomics (else the CAS fallback).
    pub native_float_atomics: bool,
    /// Subgroup size of compute kernels.
    pub subgroup_size: u32,
    /// Whether kernels use subgroup arithmetic (supported in compute and
    /// allowed by [`ContextOptions::subgroup_arithmetic`](crate::ContextOptions::subgroup_arithmetic)).
    pub subgroup_arithmetic: bool,
    /// Whether kernels use subgroup shuffles (supported in compute and
    /// allowed by [`ContextOptions::subgroup_arithmetic`](crate::ContextOptions::subgroup_arithmetic)).
    pub subgroup_shuffle: bool,
    /// Nanoseconds per timestamp tick; `None` when the compute queue has no
    /// timestamps.
    pub timestamp_period_ns: Option<f64>,
    /// Largest storage-buffer binding, in bytes.
    pub max_storage_buffer_range: u64,
    /// Largest single memory allocation, in bytes (Vulkan 1.1
    /// `maxMemoryAllocationSize`).
    pub max_memory_allocation_size: u64,
    /// Largest workgroup count per dimension.
    pub max_workgroup_count: [u32; 3],
    /// Shared memory per workgroup, in bytes.
    pub max_shared_memory: u32,
    /// Invocations per workgroup.
    pub max_workgroup_invocations: u32,
    /// Whether a dedicated transfer queue (a transfer-only family) is in use.
    pub dedicated_transfer_queue: bool,
    /// Whether the transfer path runs on the compute family as a rehearsal
    /// of a dedicated queue ([`TransferQueue::SameFamily`](crate::TransferQueue::SameFamily)).
    pub transfer_rehearsal: bool,
    /// Whether copies on the transfer queue can be timed (timestamps on
    /// its family and host query reset, since transfer queues cannot reset
    /// query pools themselves).
    pub transfer_timestamps: bool,
    /// Size of the largest device-local memory heap, bytes (system memory
    /// on CPU drivers).
    pub device_local_bytes: u64,
    /// The file compiled pipelines are kept in between processes, if any
    /// ([`ContextOptions::pipeline_cache_dir`](crate::ContextOptions)).
    pub pipeline_cache_file: Option<std::path::PathBuf>,
    /// Bytes of compiled pipelines found there when the context opened
    /// (0: a cold start, or a file that could not be used).
    pub pipeline_cache_loaded_bytes: usize,
}

impl DeviceInfo {
    /// Whether this is a CPU implementation of Vulkan (lavapipe,
    /// SwiftShader) rather than a GPU.
    pub fn is_cpu(&self) -> bool {
        self.device_type == ash::vk::PhysicalDeviceType::CPU
    }

    /// Whether this device (as configured: `LATENTAM_FLOAT_ATOMICS=cas` and
    /// `LATENTAM_SUBGROUPS=off` withdraw features) can run `kernel`, from
    /// the features the build read in its code.
    pub fn can_run(&self, kernel: &latentam_shaders::Kernel) -> bool {
        self.missing_for(kernel).is_none()
    }

    /// The first feature `kernel` needs that this device lacks.
    pub(crate) fn missing_for(&self, kernel: &latentam_shaders::Kernel) -> Option<&'static str> {
        let r = kernel.requires;
        let invocations = kernel.workgroup.iter().product::<u32>();
        if kernel.shared_bytes > self.max_shared_memory {
            Some("more shared memory per workgroup than the device has")
        } else if invocations > self.max_workgroup_invocations {
            Some("a larger workgroup than the device runs")
        } else if r.float_atomics && !self.native_float_atomics {
            Some("float atomic add (VK_EXT_shader_atomic_float)")
        } else if r.subgroup_arithmetic && !self.subgroup_arithmetic {
            Some("subgroup arithmetic in compute")
        } else if r.subgroup_shuffle && !self.subgroup_shuffle {
            Some("subgroup shuffles in compute")
        } else {
            None
        }
    }

    /// The largest buffer the engine creates for kernels: one binding
    /// ([`DeviceInfo::max_storage_buffer_range`]) in one allocation
    /// ([`DeviceInfo::max_memory_allocation_size`]). Arrays that grow with
    /// the map or the images are sized or chunked against it.
    /// Rounded down to whole 16-byte elements: NVIDIA reports a binding
    /// range of 2³² − 1 bytes, and a buffer padded up to whole elements
    /// must still fit it.
    pub fn max_buffer_bytes(&self) -> u64 {
        let alloc = if self.max_memory_allocation_size == 0 {
            u64::MAX
        } else {
            self.max_memory_allocation_size
        };
        self.max_storage_buffer_range.min(alloc) / 16 * 16
    }

    /// How `groups` workgroups along one logical dimension are split over
    /// x and y within the device's workgroup counts (x at most 65535, what
    /// every device allows); kernels recover the index with
    /// `linear_group()`.
    pub fn linear_groups(&self, groups: u32) -> [u32; 3] {
        let max_x = self.max_workgroup_count[0].min(65535);
        let x = groups.min(max_x);
        // `dispatch` records nothing for zero groups.
        let y = groups.div_ceil(x.max(1));
        [x, y, 1]
    }
}
