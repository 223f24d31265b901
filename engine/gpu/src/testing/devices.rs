//! The properties, features and limits of real GPUs the engine targets, as
//! their drivers report them, for tests of every choice the engine makes
//! from a device (buffer sizes and chunking, the window, kernel variants,
//! workgroup and shared-memory sizes, the transfer queue) on machines that
//! do not have them.
//!
//! Sources: the vulkan.gpuinfo.org reports exported into
//! KhronosGroup/Vulkan-Profiles (`profiles/LunarG/...`, file named in each
//! record), this project's own `tools/gpu-check` run on an H200, and, for
//! the Jetson, what was published from the board (named in its record);
//! memory heaps are not in the exported reports, so `device_local_bytes`
//! is the product's memory size.

use ash::vk;

use crate::DeviceInfo;

/// One queue family as `vkGetPhysicalDeviceQueueFamilyProperties` reports it.
#[derive(Clone, Copy, Debug)]
pub struct Family {
    /// `queueFlags`.
    pub flags: vk::QueueFlags,
    /// `queueCount`.
    pub count: u32,
    /// `timestampValidBits`.
    pub timestamp_bits: u32,
}

/// A real device's report.
#[derive(Clone, Debug)]
pub struct RecordedDevice {
    /// Device, driver and system, as the report names them.
    pub label: &'static str,
    /// Where the figures come from.
    pub source: &'static str,
    /// What the engine reads of it (the transfer queue fields as the
    /// engine's own choice of families makes them).
    pub info: DeviceInfo,
    /// Its queue families.
    pub families: Vec<Family>,
}

const G: vk::QueueFlags = vk::QueueFlags::GRAPHICS;
const C: vk::QueueFlags = vk::QueueFlags::COMPUTE;
const T: vk::QueueFlags = vk::QueueFlags::TRANSFER;
const S: vk::QueueFlags = vk::QueueFlags::SPARSE_BINDING;
const V: vk::QueueFlags = vk::QueueFlags::VIDEO_DECODE_KHR;
const GIB: u64 = 1 << 30;

fn family(flags: vk::QueueFlags, count: u32, timestamp_bits: u32) -> Family {
    Family {
        flags,
        count,
        timestamp_bits,
    }
}

/// `families` as `vkGetPhysicalDeviceQueueFamilyProperties` returns them.
pub fn family_properties(families: &[Family]) -> Vec<vk::QueueFamilyProperties> {
    families
        .iter()
        .map(|f| vk::QueueFamilyProperties {
            queue_flags: f.flags,
            queue_count: f.count,
            timestamp_valid_bits: f.timestamp_bits,
            ..Default::default()
        })
        .collect()
}

/// The fields every record states; the rest follow from them.
struct Report {
    label: &'static str,
    source: &'static str,
    device_type: vk::PhysicalDeviceType,
    api: (u32, u32, u32),
    float_atomic_add: bool,
    subgroup_size: u32,
    /// Arithmetic and shuffles supported in compute.
    subgroup_ops: bool,
    timestamp_period_ns: f64,
    max_storage_buffer_range: u64,
    max_memory_allocation_size: u64,
    max_workgroup_count: [u32; 3],
    max_shared_memory: u32,
    max_workgroup_invocations: u32,
    device_local_bytes: u64,
    families: Vec<Family>,
}

impl Report {
    fn record(self) -> RecordedDevice {
        let (major, minor, patch) = self.api;
        let all = family_properties(&self.families);
        let chosen =
            crate::context::QueueFamilies::choose(all, self.label, crate::TransferQueue::Auto)
                .expect("every recorded device has a compute family");
        let compute_bits = chosen.timestamp_bits(chosen.compute);
        let transfer_bits = chosen
            .transfer
            .map(|(family, _)| chosen.timestamp_bits(family));
        RecordedDevice {
            label: self.label,
            source: self.source,
            info: DeviceInfo {
                name: self.label.to_string(),
                device_type: self.device_type,
                api_version: vk::make_api_version(0, major, minor, patch),
                native_float_atomics: self.float_atomic_add,
                subgroup_size: self.subgroup_size,
                subgroup_arithmetic: self.subgroup_ops,
                subgroup_shuffle: self.subgroup_ops,
                timestamp_period_ns: (compute_bits > 0).then_some(self.timestamp_period_ns),
                max_storage_buffer_range: self.max_storage_buffer_range,
                max_memory_allocation_size: self.max_memory_allocation_size,
                max_workgroup_count: self.max_workgroup_count,
                max_shared_memory: self.max_shared_memory,
                max_workgroup_invocations: self.max_workgroup_invocations,
                dedicated_transfer_queue: transfer_bits.is_some(),
                transfer_rehearsal: false,
                transfer_timestamps: transfer_bits.map_or(compute_bits > 0, |b| b > 0),
                device_local_bytes: self.device_local_bytes,
                pipeline_cache_file: None,
                pipeline_cache_loaded_bytes: 0,
            },
            families: self.families,
        }
    }
}

/// NVIDIA's desktop and data-centre driver reports the same compute limits
/// on every GPU of the reports above (GTX 1060 to RTX 5090, drivers 535 to
/// 610): 4 GiB − 1 per storage binding, 48 KiB of shared memory, 1024
/// invocations, 2³¹ − 1 × 65535 × 65535 workgroups.
const NVIDIA_WORKGROUPS: [u32; 3] = [2_147_483_647, 65_535, 65_535];

/// The devices, most common robot and workstation targets first.
//
// Long because it is data: one entry per device, each beside the source
// its figures were read from.
pub fn recorded_devices() -> Vec<RecordedDevice> {
    use vk::PhysicalDeviceType as Kind;
    vec![
        Report {
            label: "NVIDIA GeForce RTX 4070 driver 551.61.0.0 on Windows 11",
            source: "vulkan.gpuinfo.org via KhronosGroup/Vulkan-Profiles \
                     profiles/LunarG/VP_LUNARG_desktop_baseline_2024/\
                     vp_gpuinfo_nvidia_geforce_rtx_4070_551_61_0_0_windows_11.json; 12 GB",
            device_type: Kind::DISCRETE_GPU,
            api: (1, 3, 277),
            float_atomic_add: true,
            subgroup_size: 32,
            subgroup_ops: true,
            timestamp_period_ns: 1.0,
            max_storage_buffer_range: 4_294_967_295,
            max_memory_allocation_size: 4_292_870_144,
            max_workgroup_count: NVIDIA_WORKGROUPS,
            max_shared_memory: 49_152,
            max_workgroup_invocations: 1024,
            device_local_bytes: 12 * GIB,
            families: vec![
                family(G | C | T | S, 16, 64),
                family(T | S, 2, 64),
                family(C | T | S, 8, 64),
                family(T | S | V, 1, 32),
                family(T | S | vk::QueueFlags::VIDEO_ENCODE_KHR, 1, 32),
                family(T | S, 1, 64),
            ],
        },
        Report {
            label: "NVIDIA GeForce RTX 5080 driver 610.62.0.0 on Windows 11",
            source: "vulkan.gpuinfo.org via KhronosGroup/Vulkan-Profiles \
                     profiles/LunarG/VP_LUNARG_desktop_baseline_2026/\
                     vp_gpuinfo_nvidia_geforce_rtx_5080_610_62_0_0_windows_11.json \
                     (maxMemoryAllocationSize 2⁶³ − 1 from driver 610 on); 16 GB",
            device_type: Kind::DISCRETE_GPU,
            api: (1, 4, 341),
            float_atomic_add: true,
            subgroup_size: 32,
            subgroup_ops: true,
            timestamp_period_ns: 1.0,
            max_storage_buffer_range: 4_294_967_295,
            max_memory_allocation_size: i64::MAX as u64,
            max_workgroup_count: NVIDIA_WORKGROUPS,
            max_shared_memory: 49_152,
            max_workgroup_invocations: 1024,
            device_local_bytes: 16 * GIB,
            families: vec![
                family(G | C | T | S, 16, 64),
                family(T | S, 2, 64),
                family(C | T | S, 8, 64),
                family(T | S | V, 2, 32),
                family(T | S | V, 2, 32),
                family(T | S, 1, 64),
            ],
        },
        Report {
            label: "NVIDIA Tegra Orin (nvgpu) driver 595.78 (Jetson Orin Nano 8 GB)",
            source: "name, type (integrated) and driver from a published vulkaninfo of the \
                     board; subgroup 32 and 48 KiB of shared memory measured on it by a \
                     published shader tuning guide; the other limits are those NVIDIA's \
                     driver reports on every GPU above (not recorded from the board); \
                     one 8 GB memory shared with the CPU",
            device_type: Kind::INTEGRATED_GPU,
            api: (1, 4, 329),
            float_atomic_add: true,
            subgroup_size: 32,
            subgroup_ops: true,
            timestamp_period_ns: 1.0,
            max_storage_buffer_range: 4_294_967_295,
            max_memory_allocation_size: 4_292_870_144,
            max_workgroup_count: NVIDIA_WORKGROUPS,
            max_shared_memory: 49_152,
            max_workgroup_invocations: 1024,
            device_local_bytes: 8 * GIB,
            families: vec![
                family(G | C | T | S, 16, 64),
                family(T | S, 2, 64),
                family(C | T | S, 8, 64),
            ],
        },
        Report {
            label: "NVIDIA H200 driver 580.159.04 on Linux",
            source: "this project's tools/gpu-check (devices.log); workgroup and \
                     shared-memory limits NVIDIA's as above; 143771 MiB",
            device_type: Kind::DISCRETE_GPU,
            api: (1, 4, 312),
            float_atomic_add: true,
            subgroup_size: 32,
            subgroup_ops: true,
            timestamp_period_ns: 1.0,
            max_storage_buffer_range: 4_294_967_295,
            max_memory_allocation_size: 4_292_870_144,
            max_workgroup_count: NVIDIA_WORKGROUPS,
            max_shared_memory: 49_152,
            max_workgroup_invocations: 1024,
            device_local_bytes: 143_771 << 20,
            families: vec![
                family(G | C | T | S, 16, 64),
                family(T | S, 2, 64),
                family(C | T | S, 8, 64),
            ],
        },
        Report {
            label: "AMD Radeon RX 7800 XT (RADV NAVI32) driver 24.0.99 on Arch (RDNA3)",
            source: "vulkan.gpuinfo.org via KhronosGroup/Vulkan-Profiles \
                     profiles/LunarG/VP_LUNARG_desktop_baseline_2024/\
                     vp_gpuinfo_amd_radeon_rx_7800_xt__radv_navi32__24_0_99_arch_unknown.json; \
                     16 GB",
            device_type: Kind::DISCRETE_GPU,
            api: (1, 3, 278),
            float_atomic_add: true,
            subgroup_size: 64,
            subgroup_ops: true,
            timestamp_period_ns: 10.0,
            max_storage_buffer_range: 4_294_967_295,
            max_memory_allocation_size: 4_294_967_292,
            max_workgroup_count: [65_535; 3],
            max_shared_memory: 65_536,
            max_workgroup_invocations: 1024,
            device_local_bytes: 16 * GIB,
            families: vec![
                family(G | C | T, 1, 64),
                family(C | T, 4, 64),
                family(S, 1, 64),
            ],
        },
        Report {
            label: "AMD Radeon RX 6600 (RADV NAVI23) driver 23.2.99 on EndeavourOS (RDNA2)",
            source: "vulkan.gpuinfo.org via KhronosGroup/Vulkan-Profiles \
                     profiles/LunarG/VP_LUNARG_desktop_max_2024/\
                     vp_gpuinfo_amd_radeon_rx_6600__radv_navi23__23_2_99_endeavouros_unknown.json \
                     (no float atomic add on buffers); 8 GB",
            device_type: Kind::DISCRETE_GPU,
            api: (1, 3, 255),
            float_atomic_add: false,
            subgroup_size: 64,
            subgroup_ops: true,
            timestamp_period_ns: 10.0,
            max_storage_buffer_range: 4_294_967_295,
            max_memory_allocation_size: 4_294_967_292,
            max_workgroup_count: [65_535; 3],
            max_shared_memory: 65_536,
            max_workgroup_invocations: 1024,
            device_local_bytes: 8 * GIB,
            families: vec![family(G | C | T | S, 1, 64), family(C | T | S, 4, 64)],
        },
        Report {
            label: "Intel(R) Arc(tm) A770 Graphics (DG2) driver 26.1.2 on Arch",
            source: "vulkan.gpuinfo.org via KhronosGroup/Vulkan-Profiles \
                     profiles/LunarG/VP_LUNARG_desktop_baseline_2026/\
                     vp_gpuinfo_intel_r__arc_tm__a770_graphics__dg2__26_1_2_arch_unknown.json \
                     (one queue family, 36 timestamp bits); 16 GB",
            device_type: Kind::DISCRETE_GPU,
            api: (1, 4, 348),
            float_atomic_add: true,
            subgroup_size: 32,
            subgroup_ops: true,
            timestamp_period_ns: 52.0833,
            max_storage_buffer_range: 4_294_967_295,
            max_memory_allocation_size: 37_801_967_616,
            max_workgroup_count: [2_147_483_647, 65_535, 65_535],
            max_shared_memory: 49_152,
            max_workgroup_invocations: 1024,
            device_local_bytes: 16 * GIB,
            families: vec![family(G | C | T | S, 1, 36)],
        },
    ]
    .into_iter()
    .map(Report::record)
    .collect()
}
