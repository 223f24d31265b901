//! Choosing a physical device and opening it: the queue families (an
//! async transfer queue where the device has one), the features and
//! extensions the kernels need, checked rather than assumed.

use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};

use ash::vk;

use super::{
    ContextOptions, Device, DeviceInfo, FloatAtomics, Queue, TransferQueue, ValidationLog,
};
use crate::counters::CallCounters;
use crate::memory::MemoryAccounting;
use crate::objects::ObjectCounts;
use crate::pipeline::PipelineCache;
use crate::profiler::Profiler;
use crate::retire::RetireQueue;
use latentam_base::{Error, Result, VkContext};

/// What to do when no Vulkan device is found.
pub(super) const INSTALL_HINT: &str =
    "install a Vulkan driver: on Debian/Ubuntu `sudo apt-get install \
     libvulkan1 mesa-vulkan-drivers` provides lavapipe, a CPU implementation; for a GPU \
     install its vendor driver";

/// A physical device that can run the engine.
pub(super) struct Candidate {
    pub(super) physical: vk::PhysicalDevice,
    pub(super) name: String,
    pub(super) props: vk::PhysicalDeviceProperties,
}

/// Preference of a device type: discrete GPUs first, CPUs last.
pub(super) fn rank(t: vk::PhysicalDeviceType) -> u32 {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => 4,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 3,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 1,
        _ => 0,
    }
}

/// Destroys a half-built instance on an early return.
pub(super) struct InstanceGuard(pub(super) Option<ash::Instance>);

impl Drop for InstanceGuard {
    fn drop(&mut self) {
        if let Some(i) = self.0.take() {
            // SAFETY: only reached when `Device` was never built.
            unsafe { i.destroy_instance(None) };
        }
    }
}

pub(super) struct DebugGuard(
    pub(super) Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
);

impl Drop for DebugGuard {
    fn drop(&mut self) {
        if let Some((du, m)) = self.0.take() {
            // SAFETY: only reached when `Device` was never built.
            unsafe { du.destroy_debug_utils_messenger(m, None) };
        }
    }
}

pub(super) fn pick_device(instance: &ash::Instance, wanted: Option<&str>) -> Result<Candidate> {
    // SAFETY: enumeration on a valid instance.
    let physicals =
        unsafe { instance.enumerate_physical_devices() }.vk("vkEnumeratePhysicalDevices")?;
    let mut all = Vec::new();
    for p in physicals {
        // SAFETY: valid physical device handle.
        let props = unsafe { instance.get_physical_device_properties(p) };
        let name = props
            .device_name_as_c_str()
            .map(|c| c.to_string_lossy().into_owned())
            .unwrap_or_default();
        all.push(Candidate {
            physical: p,
            name,
            props,
        });
    }
    if all.is_empty() {
        return Err(Error::NoVulkan(format!(
            "no Vulkan device found; {INSTALL_HINT}"
        )));
    }
    let names = || {
        all.iter()
            .enumerate()
            .map(|(i, c)| format!("{i}: {}", c.name))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let usable = |c: &Candidate| c.props.api_version >= vk::API_VERSION_1_2;
    let chosen = match wanted {
        Some(w) => {
            let idx = match w.parse::<usize>() {
                Ok(i) if i < all.len() => Some(i),
                Ok(_) => None,
                Err(_) => all
                    .iter()
                    .position(|c| c.name.to_lowercase().contains(&w.to_lowercase())),
            };
            let i = idx.ok_or_else(|| {
                Error::config(
                    "LATENTAM_DEVICE",
                    format!("{w} matches no device (available: {})", names()),
                )
            })?;
            if !usable(&all[i]) {
                return Err(Error::Unsupported(format!(
                    "{} supports only Vulkan {}.{}; the engine needs 1.2",
                    all[i].name,
                    vk::api_version_major(all[i].props.api_version),
                    vk::api_version_minor(all[i].props.api_version)
                )));
            }
            i
        }
        None => all
            .iter()
            .enumerate()
            .filter(|(_, c)| usable(c))
            .max_by_key(|(i, c)| (rank(c.props.device_type), std::cmp::Reverse(*i)))
            .map(|(i, _)| i)
            .ok_or_else(|| {
                Error::Unsupported(format!(
                    "no device supports Vulkan 1.2 (available: {}); {INSTALL_HINT}",
                    names()
                ))
            })?,
    };
    Ok(all.swap_remove(chosen))
}

pub(super) fn open_device(
    entry: ash::Entry,
    instance: ash::Instance,
    debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    validation_log: Arc<ValidationLog>,
    c: Candidate,
    options: &ContextOptions,
) -> Result<Device> {
    let p = c.physical;
    let families = QueueFamilies::of(&instance, p, &c.name, options.transfer_queue)?;
    let features = Features::of(&instance, p, &c.name, options)?;
    let raw = create_device(&instance, p, &families, &features)?;
    let (compute, transfer) = match create_queues(&raw, &families) {
        Ok(q) => q,
        Err(e) => {
            // SAFETY: nothing else was created on the device.
            unsafe { raw.destroy_device(None) };
            return Err(e);
        }
    };
    let allocator =
        gpu_allocator::vulkan::Allocator::new(&gpu_allocator::vulkan::AllocatorCreateDesc {
            instance: instance.clone(),
            device: raw.clone(),
            physical_device: p,
            debug_settings: Default::default(),
            buffer_device_address: false,
            allocation_sizes: Default::default(),
        });
    let allocator = match allocator {
        Ok(a) => a,
        Err(e) => {
            // SAFETY: only the semaphores exist.
            unsafe {
                raw.destroy_semaphore(compute.timeline, None);
                if let Some(t) = &transfer {
                    raw.destroy_semaphore(t.timeline, None);
                }
                raw.destroy_device(None);
            }
            return Err(Error::OutOfMemory(format!("creating the allocator: {e}")));
        }
    };
    let cache_file = options
        .pipeline_cache_dir
        .as_deref()
        .map(|d| crate::pipeline_cache_file::path_for(d, &c.props));
    let (pipeline_cache, loaded) = create_pipeline_cache(&raw, cache_file.as_deref(), &c.props);
    let mut info = device_info(
        &instance,
        c,
        options,
        &families,
        &features,
        transfer.as_ref(),
    );
    info.pipeline_cache_file = cache_file;
    info.pipeline_cache_loaded_bytes = loaded;
    let profiler = (options.profiling && info.timestamp_period_ns.is_some())
        .then(|| Mutex::new(Profiler::default()));
    Ok(Device {
        _entry: entry,
        instance,
        debug,
        validation_log,
        raw,
        info,
        compute,
        transfer,
        allocator: Mutex::new(Some(allocator)),
        memory: MemoryAccounting::new(options.memory_budget),
        retired: RetireQueue::default(),
        objects: ObjectCounts::default(),
        pipelines: PipelineCache::rejecting(options.rejected_kernels.clone()),
        pipeline_cache,
        profiler,
        host_query_reset: features.host_query_reset,
        calls: CallCounters::default(),
        work: Default::default(),
        opened: std::time::Instant::now(),
        ready_after: Mutex::new(None),
        build_times: Mutex::new(Vec::new()),
    })
}

/// The queue families the engine uses: one with compute, and a transfer
/// family without compute or graphics (a DMA engine) where there is one.
pub(crate) struct QueueFamilies {
    all: Vec<vk::QueueFamilyProperties>,
    pub(crate) compute: u32,
    /// The transfer path's family and queue index in it.
    pub(crate) transfer: Option<(u32, u32)>,
}

impl QueueFamilies {
    fn of(
        instance: &ash::Instance,
        p: vk::PhysicalDevice,
        name: &str,
        choice: TransferQueue,
    ) -> Result<Self> {
        // SAFETY: queries on a valid physical device.
        let all = unsafe { instance.get_physical_device_queue_family_properties(p) };
        Self::choose(all, name, choice)
    }

    /// The families of a device with queue families `all`.
    pub(crate) fn choose(
        all: Vec<vk::QueueFamilyProperties>,
        name: &str,
        choice: TransferQueue,
    ) -> Result<Self> {
        let compute = all
            .iter()
            .position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE))
            .ok_or_else(|| Error::Unsupported(format!("{name} has no compute queue")))?
            as u32;
        let dedicated = || {
            all.iter()
                .position(|f| {
                    f.queue_flags.contains(vk::QueueFlags::TRANSFER)
                        && !f.queue_flags.contains(vk::QueueFlags::COMPUTE)
                        && !f.queue_flags.contains(vk::QueueFlags::GRAPHICS)
                })
                .map(|i| (i as u32, 0))
        };
        let transfer = match choice {
            TransferQueue::Auto => dedicated(),
            TransferQueue::Off => None,
            // A second queue of the compute family where it has one, else
            // the compute queue itself (index 0, shared).
            TransferQueue::SameFamily => {
                let count = all[compute as usize].queue_count;
                Some((compute, u32::from(count > 1)))
            }
        };
        Ok(QueueFamilies {
            all,
            compute,
            transfer,
        })
    }

    /// Valid bits of a family's timestamps (0: none).
    pub(crate) fn timestamp_bits(&self, family: u32) -> u32 {
        self.all[family as usize].timestamp_valid_bits
    }
}

/// What the device supports of what the engine enables, and the
/// properties it reads.
struct Features {
    host_query_reset: bool,
    native_float_atomics: bool,
    subgroup_size: u32,
    /// The subgroup operations compute shaders may use (none when the
    /// device offers them to other stages only).
    compute_subgroup_ops: vk::SubgroupFeatureFlags,
    max_memory_allocation_size: u64,
}

impl Features {
    fn of(
        instance: &ash::Instance,
        p: vk::PhysicalDevice,
        name: &str,
        options: &ContextOptions,
    ) -> Result<Self> {
        // SAFETY: valid physical device.
        let exts = unsafe { instance.enumerate_device_extension_properties(p) }
            .vk("vkEnumerateDeviceExtensionProperties")?;
        let has_atomic_float_ext = exts
            .iter()
            .any(|e| e.extension_name_as_c_str().ok() == Some(ash::ext::shader_atomic_float::NAME));
        let mut atomic_feats = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default();
        let mut v12 = vk::PhysicalDeviceVulkan12Features::default();
        {
            let mut feats2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut v12);
            if has_atomic_float_ext {
                feats2 = feats2.push_next(&mut atomic_feats);
            }
            // SAFETY: valid chain of feature structs.
            unsafe { instance.get_physical_device_features2(p, &mut feats2) };
        }
        if v12.timeline_semaphore == vk::FALSE {
            return Err(Error::Unsupported(format!(
                "{name} lacks timeline semaphores (Vulkan 1.2)"
            )));
        }
        let mut subgroup = vk::PhysicalDeviceSubgroupProperties::default();
        let mut maintenance3 = vk::PhysicalDeviceMaintenance3Properties::default();
        {
            let mut props2 = vk::PhysicalDeviceProperties2::default()
                .push_next(&mut subgroup)
                .push_next(&mut maintenance3);
            // SAFETY: valid chain.
            unsafe { instance.get_physical_device_properties2(p, &mut props2) };
        }
        Ok(Features {
            host_query_reset: v12.host_query_reset == vk::TRUE,
            native_float_atomics: has_atomic_float_ext
                && atomic_feats.shader_buffer_float32_atomic_add == vk::TRUE
                && options.float_atomics == FloatAtomics::Auto,
            subgroup_size: subgroup.subgroup_size,
            compute_subgroup_ops: if subgroup
                .supported_stages
                .contains(vk::ShaderStageFlags::COMPUTE)
            {
                subgroup.supported_operations
            } else {
                vk::SubgroupFeatureFlags::empty()
            },
            max_memory_allocation_size: maintenance3.max_memory_allocation_size,
        })
    }
}

/// The logical device with the queues and features the engine uses.
fn create_device(
    instance: &ash::Instance,
    p: vk::PhysicalDevice,
    families: &QueueFamilies,
    features: &Features,
) -> Result<ash::Device> {
    let priorities = [1.0f32, 1.0];
    // One create info per family: the compute family asks for a second
    // queue when the transfer path uses one of its own there.
    let compute_queues = match families.transfer {
        Some((f, 1)) if f == families.compute => 2,
        _ => 1,
    };
    let mut queue_infos = vec![vk::DeviceQueueCreateInfo::default()
        .queue_family_index(families.compute)
        .queue_priorities(&priorities[..compute_queues])];
    if let Some((t, _)) = families.transfer.filter(|t| t.0 != families.compute) {
        queue_infos.push(
            vk::DeviceQueueCreateInfo::default()
                .queue_family_index(t)
                .queue_priorities(&priorities[..1]),
        );
    }
    let mut enable12 = vk::PhysicalDeviceVulkan12Features::default()
        .timeline_semaphore(true)
        .host_query_reset(features.host_query_reset);
    let mut enable_atomic = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default()
        .shader_buffer_float32_atomic_add(true);
    let mut ext_names: Vec<*const i8> = Vec::new();
    let mut create = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queue_infos)
        .push_next(&mut enable12);
    if features.native_float_atomics {
        ext_names.push(ash::ext::shader_atomic_float::NAME.as_ptr());
        create = create.push_next(&mut enable_atomic);
    }
    let create = create.enabled_extension_names(&ext_names);
    // SAFETY: valid create info built from queried support.
    unsafe { instance.create_device(p, &create, None) }.vk("vkCreateDevice")
}

/// The compute queue and, where the device has one, the transfer queue,
/// each with its timeline semaphore. On failure what was created is
/// destroyed (the device is the caller's).
fn create_queues(raw: &ash::Device, families: &QueueFamilies) -> Result<(Queue, Option<Queue>)> {
    let make_queue = |family: u32, handle: Arc<Mutex<vk::Queue>>| -> Result<Queue> {
        let mut ti = vk::SemaphoreTypeCreateInfo::default()
            .semaphore_type(vk::SemaphoreType::TIMELINE)
            .initial_value(0);
        let ci = vk::SemaphoreCreateInfo::default().push_next(&mut ti);
        // SAFETY: valid device; destroyed in `Device::drop`.
        let timeline = unsafe { raw.create_semaphore(&ci, None) }.vk("vkCreateSemaphore")?;
        Ok(Queue {
            family,
            queue: handle,
            timeline,
            submitted: AtomicU64::new(0),
            attached: AtomicU64::new(0),
            timestamp_bits: families.timestamp_bits(family),
        })
    };
    // SAFETY: each (family, index) below was requested at device creation.
    let get = |family: u32, index: u32| unsafe { raw.get_device_queue(family, index) };
    let compute_handle = Arc::new(Mutex::new(get(families.compute, 0)));
    let compute = make_queue(families.compute, compute_handle.clone())?;
    let transfer = families.transfer.map(|(family, index)| {
        let handle = if family == families.compute && index == 0 {
            compute_handle.clone()
        } else {
            Arc::new(Mutex::new(get(family, index)))
        };
        make_queue(family, handle)
    });
    match transfer.transpose() {
        Ok(transfer) => Ok((compute, transfer)),
        Err(e) => {
            // SAFETY: only the compute semaphore exists.
            unsafe { raw.destroy_semaphore(compute.timeline, None) };
            Err(e)
        }
    }
}

/// What the engine reads of the opened device.
fn device_info(
    instance: &ash::Instance,
    c: Candidate,
    options: &ContextOptions,
    families: &QueueFamilies,
    features: &Features,
    transfer: Option<&Queue>,
) -> DeviceInfo {
    let limits = c.props.limits;
    let timestamp_valid_bits = families.timestamp_bits(families.compute);
    // SAFETY: valid physical device.
    let mem = unsafe { instance.get_physical_device_memory_properties(c.physical) };
    let device_local_bytes = mem.memory_heaps[..mem.memory_heap_count as usize]
        .iter()
        .filter(|h| h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
        .map(|h| h.size)
        .max()
        .unwrap_or(0);
    let timestamp_period_ns = (timestamp_valid_bits > 0).then_some(limits.timestamp_period as f64);
    // Subgroup operations kernels may use: allowed, and supported in compute.
    let subgroup_ops = |ops: vk::SubgroupFeatureFlags| {
        options.subgroup_arithmetic && features.compute_subgroup_ops.contains(ops)
    };
    DeviceInfo {
        name: c.name,
        device_type: c.props.device_type,
        api_version: c.props.api_version,
        native_float_atomics: features.native_float_atomics,
        subgroup_size: features.subgroup_size,
        subgroup_arithmetic: subgroup_ops(
            vk::SubgroupFeatureFlags::BASIC
                | vk::SubgroupFeatureFlags::VOTE
                | vk::SubgroupFeatureFlags::ARITHMETIC,
        ),
        subgroup_shuffle: subgroup_ops(
            vk::SubgroupFeatureFlags::BASIC | vk::SubgroupFeatureFlags::SHUFFLE,
        ),
        timestamp_period_ns,
        max_storage_buffer_range: (limits.max_storage_buffer_range as u64)
            .min(options.max_buffer_bytes.unwrap_or(u64::MAX)),
        max_memory_allocation_size: features
            .max_memory_allocation_size
            .min(options.max_buffer_bytes.unwrap_or(u64::MAX)),
        max_workgroup_count: limits.max_compute_work_group_count,
        max_shared_memory: limits.max_compute_shared_memory_size,
        max_workgroup_invocations: limits.max_compute_work_group_invocations,
        dedicated_transfer_queue: transfer.is_some_and(|t| t.family != families.compute),
        transfer_rehearsal: transfer.is_some_and(|t| t.family == families.compute),
        transfer_timestamps: match transfer {
            Some(t) => {
                t.timestamp_bits > 0 && features.host_query_reset && timestamp_valid_bits > 0
            }
            None => timestamp_valid_bits > 0,
        },
        device_local_bytes,
        pipeline_cache_file: None,
        pipeline_cache_loaded_bytes: 0,
    }
}

/// The driver's pipeline cache, seeded from `file` when it holds a usable
/// cache of this device; with the bytes it was seeded with. A cache that
/// cannot be created leaves pipelines uncached (a warning, not an error).
fn create_pipeline_cache(
    raw: &ash::Device,
    file: Option<&std::path::Path>,
    props: &vk::PhysicalDeviceProperties,
) -> (vk::PipelineCache, usize) {
    let data = file
        .and_then(|f| crate::pipeline_cache_file::load(f, props))
        .unwrap_or_default();
    for initial in [&data[..], &[]] {
        let ci = vk::PipelineCacheCreateInfo::default().initial_data(initial);
        // SAFETY: valid device; the data was checked against the device's
        // own cache header.
        match unsafe { raw.create_pipeline_cache(&ci, None) } {
            Ok(c) => return (c, initial.len()),
            Err(e) => log::warn!("vkCreatePipelineCache with {} bytes: {e}", initial.len()),
        }
    }
    (vk::PipelineCache::null(), 0)
}
