//! Vulkan instance, device and queue selection; the shared device state that
//! every GPU object holds on to.

use std::ffi::{c_void, CStr, CString};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use ash::vk;

use super::counters::{CallCounters, GpuCalls};
use super::memory::MemoryAccounting;
use super::objects::ObjectCounts;
use super::pipeline::PipelineCache;
use super::profiler::Profiler;
use super::retire::{RetireQueue, Retired};
use crate::error::{Error, Result, VkContext};

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// Whether to load the Khronos validation layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Validation {
    /// Never (the default for production use).
    #[default]
    Off,
    /// When the layer is installed.
    IfAvailable,
    /// Fail if the layer is not installed (tests).
    Required,
}

/// How kernels add floats atomically.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FloatAtomics {
    /// Native `shaderBufferFloat32AtomicAdd` when the device has it, else CAS.
    #[default]
    Auto,
    /// Always the compare-and-swap fallback (to test it, or to work around a
    /// driver).
    CompareAndSwap,
}

/// Options for [`Context::new`]. `Default` reads the environment:
/// `LATENTAM_DEVICE` (index or case-insensitive name substring),
/// `LATENTAM_VALIDATION=1` (require the validation layer),
/// `LATENTAM_FLOAT_ATOMICS=cas` (force the CAS fallback),
/// `LATENTAM_SUBGROUPS=off` (do not use subgroup arithmetic),
/// `LATENTAM_MAX_BUFFER_BYTES=N` (cap the largest buffer below the device's).
#[derive(Clone, Debug)]
pub struct ContextOptions {
    /// Device to use: an index into the enumeration or a name substring;
    /// `None` picks the best (discrete > integrated > virtual > CPU).
    pub device: Option<String>,
    /// Validation layer policy.
    pub validation: Validation,
    /// Record GPU timestamps around every dispatch.
    pub profiling: bool,
    /// Float-atomic strategy.
    pub float_atomics: FloatAtomics,
    /// GPU memory budget in bytes for this context (`None` = device limits).
    pub memory_budget: Option<u64>,
    /// Use subgroup operations (`subgroupAdd`, shuffles) where the device
    /// supports them in compute shaders; `false` selects kernels that do
    /// without.
    pub subgroup_arithmetic: bool,
    /// Caps the largest buffer the engine creates (the storage-buffer
    /// binding and single-allocation limits of [`DeviceInfo`]) below the
    /// device's own: to leave headroom, or to rehearse a device with small
    /// limits (`LATENTAM_MAX_BUFFER_BYTES`). `None`: the device's limits.
    pub max_buffer_bytes: Option<u64>,
}

impl Default for ContextOptions {
    fn default() -> Self {
        let env = |k: &str| std::env::var(k).ok().filter(|v| !v.is_empty());
        Self {
            device: env("LATENTAM_DEVICE"),
            validation: match env("LATENTAM_VALIDATION").as_deref() {
                Some("1") | Some("required") => Validation::Required,
                Some("auto") => Validation::IfAvailable,
                _ => Validation::Off,
            },
            profiling: false,
            float_atomics: match env("LATENTAM_FLOAT_ATOMICS").as_deref() {
                Some("cas") => FloatAtomics::CompareAndSwap,
                _ => FloatAtomics::Auto,
            },
            memory_budget: None,
            subgroup_arithmetic: env("LATENTAM_SUBGROUPS").as_deref() != Some("off"),
            max_buffer_bytes: env("LATENTAM_MAX_BUFFER_BYTES").and_then(|v| v.parse().ok()),
        }
    }
}

/// What the selected device offers, as the engine uses it.
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
    /// allowed by [`ContextOptions::subgroup_arithmetic`]).
    pub subgroup_arithmetic: bool,
    /// Whether kernels use subgroup shuffles (supported in compute and
    /// allowed by [`ContextOptions::subgroup_arithmetic`]).
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
    /// Whether a dedicated transfer queue is in use.
    pub dedicated_transfer_queue: bool,
    /// Whether copies on the transfer queue can be timed (timestamps on
    /// its family and host query reset, since transfer queues cannot reset
    /// query pools themselves).
    pub transfer_timestamps: bool,
    /// Size of the largest device-local memory heap, bytes (system memory
    /// on CPU drivers).
    pub device_local_bytes: u64,
}

impl DeviceInfo {
    /// Whether this device (as configured: `LATENTAM_FLOAT_ATOMICS=cas` and
    /// `LATENTAM_SUBGROUPS=off` withdraw features) can run `kernel`, from
    /// the features the build read in its code.
    pub fn can_run(&self, kernel: &latentam_shaders::Kernel) -> bool {
        self.missing_for(kernel).is_none()
    }

    /// The first feature `kernel` needs that this device lacks.
    pub(crate) fn missing_for(&self, kernel: &latentam_shaders::Kernel) -> Option<&'static str> {
        let r = kernel.requires;
        if r.float_atomics && !self.native_float_atomics {
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
    pub fn max_buffer_bytes(&self) -> u64 {
        let alloc = if self.max_memory_allocation_size == 0 {
            u64::MAX
        } else {
            self.max_memory_allocation_size
        };
        self.max_storage_buffer_range.min(alloc)
    }
}

/// Validation messages collected from the debug messenger. Tests hold a clone
/// and assert it stayed empty after the context is gone (leaks are reported
/// at device destruction).
#[derive(Debug, Default)]
pub struct ValidationLog {
    errors: Mutex<Vec<String>>,
}

impl ValidationLog {
    /// Every validation error so far.
    pub fn errors(&self) -> Vec<String> {
        self.errors
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the layer passes valid callback data; `user` is the
    // `ValidationLog` kept alive by the `Device` that owns the messenger.
    let (msg, log) = unsafe {
        let msg = if data.is_null() || (*data).p_message.is_null() {
            String::from("(no message)")
        } else {
            CStr::from_ptr((*data).p_message)
                .to_string_lossy()
                .into_owned()
        };
        (msg, &*(user as *const ValidationLog))
    };
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        log::error!("vulkan validation: {msg}");
        log.errors
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push(msg);
    } else {
        log::warn!("vulkan validation: {msg}");
    }
    vk::FALSE
}

/// One queue and the timeline semaphore its submissions signal.
pub(crate) struct Queue {
    pub family: u32,
    pub queue: Mutex<vk::Queue>,
    pub timeline: vk::Semaphore,
    /// Last value handed to a submission.
    pub submitted: AtomicU64,
    /// Valid bits of this family's timestamps (0: none).
    pub timestamp_bits: u32,
}

/// The device and everything tied to its lifetime. Held by `Arc` in every GPU
/// object, so it is destroyed last.
pub(crate) struct Device {
    /// Keeps the Vulkan loader loaded until the instance is destroyed.
    _entry: ash::Entry,
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
    pub profiler: Option<Mutex<Profiler>>,
    /// Query pools can be reset from the host (Vulkan 1.2 `hostQueryReset`).
    pub host_query_reset: bool,
    /// Submissions, host waits and dispatches so far.
    pub(crate) calls: CallCounters,
}

impl Device {
    /// Families that buffers must be shareable between.
    pub fn queue_families(&self) -> Vec<u32> {
        let mut f = vec![self.compute.family];
        if let Some(t) = &self.transfer {
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

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: nothing else references the device any more (this is the
        // last `Arc`); wait for the GPU, then destroy children before parents.
        unsafe {
            let _ = self.raw.device_wait_idle();
            let all = self.retired.take_all();
            self.destroy(all);
            self.pipelines.destroy_all(&self.raw);
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

/// The engine's handle on one Vulkan device. Cheap to clone; every GPU object
/// created from it keeps the device alive.
///
/// ```no_run
/// let ctx = latentam::gpu::Context::new(Default::default())?;
/// println!("running on {}", ctx.info().name);
/// # Ok::<(), latentam::Error>(())
/// ```
#[derive(Clone)]
pub struct Context {
    pub(crate) dev: Arc<Device>,
}

impl std::fmt::Debug for Context {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Context")
            .field("device", &self.dev.info.name)
            .finish()
    }
}

const INSTALL_HINT: &str = "install a Vulkan driver: on Debian/Ubuntu `sudo apt-get install \
     libvulkan1 mesa-vulkan-drivers` provides lavapipe, a CPU implementation; for a GPU \
     install its vendor driver";

struct Candidate {
    physical: vk::PhysicalDevice,
    name: String,
    props: vk::PhysicalDeviceProperties,
}

fn rank(t: vk::PhysicalDeviceType) -> u32 {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => 4,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 3,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 1,
        _ => 0,
    }
}

impl Context {
    /// Opens the device chosen by `options`.
    ///
    /// Fails with [`Error::NoVulkan`] (saying how to install a driver) when
    /// there is no Vulkan loader or device, and with [`Error::Unsupported`]
    /// when the device lacks Vulkan 1.2 timeline semaphores or a compute
    /// queue.
    pub fn new(options: ContextOptions) -> Result<Self> {
        // SAFETY: loading the system Vulkan loader; failure is reported.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| {
            Error::NoVulkan(format!(
                "cannot load the Vulkan loader ({e}); {INSTALL_HINT}"
            ))
        })?;

        // SAFETY: plain enumeration calls on a loaded entry.
        let layers = unsafe { entry.enumerate_instance_layer_properties() }
            .vk("vkEnumerateInstanceLayerProperties")?;
        let have_validation = layers
            .iter()
            .any(|l| l.layer_name_as_c_str().ok() == Some(VALIDATION_LAYER));
        let use_validation = match options.validation {
            Validation::Off => false,
            Validation::IfAvailable => have_validation,
            Validation::Required if !have_validation => {
                return Err(Error::NoVulkan(
                    "the Vulkan validation layer VK_LAYER_KHRONOS_validation is required but \
                     not installed; on Debian/Ubuntu `sudo apt-get install \
                     vulkan-validationlayers`"
                        .into(),
                ))
            }
            Validation::Required => true,
        };

        let app_name = CString::new("latentam").unwrap();
        let app = vk::ApplicationInfo::default()
            .application_name(&app_name)
            .engine_name(&app_name)
            .api_version(vk::API_VERSION_1_2);
        let layer_ptrs: Vec<*const i8> = if use_validation {
            vec![VALIDATION_LAYER.as_ptr()]
        } else {
            vec![]
        };
        let ext_ptrs: Vec<*const i8> = if use_validation {
            vec![ash::ext::debug_utils::NAME.as_ptr()]
        } else {
            vec![]
        };
        let validation_log = Arc::new(ValidationLog::default());
        let severity = vk::DebugUtilsMessageSeverityFlagsEXT::ERROR
            | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING;
        let types = vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
            | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
            | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE;
        let mut messenger_info = vk::DebugUtilsMessengerCreateInfoEXT::default()
            .message_severity(severity)
            .message_type(types)
            .pfn_user_callback(Some(debug_callback))
            .user_data(Arc::as_ptr(&validation_log) as *mut c_void);
        let mut create = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layer_ptrs)
            .enabled_extension_names(&ext_ptrs);
        if use_validation {
            // Also catches errors in instance creation and destruction.
            create = create.push_next(&mut messenger_info);
        }
        // SAFETY: valid create info; the instance is destroyed by `Device`.
        let instance = match unsafe { entry.create_instance(&create, None) } {
            Ok(i) => i,
            Err(vk::Result::ERROR_INCOMPATIBLE_DRIVER) => {
                return Err(Error::NoVulkan(format!(
                    "no Vulkan 1.2 driver found; {INSTALL_HINT}"
                )))
            }
            Err(e) => {
                return Err(Error::Vulkan {
                    call: "vkCreateInstance",
                    result: e,
                })
            }
        };
        // From here on, a failure must destroy the instance.
        let guard = InstanceGuard(Some(instance.clone()));

        let debug = if use_validation {
            let du = ash::ext::debug_utils::Instance::new(&entry, &instance);
            // SAFETY: valid create info; destroyed by `Device`.
            let m = unsafe { du.create_debug_utils_messenger(&messenger_info, None) }
                .vk("vkCreateDebugUtilsMessengerEXT")?;
            Some((du, m))
        } else {
            None
        };
        let debug_guard = DebugGuard(debug.clone());

        let candidate = pick_device(&instance, options.device.as_deref())?;
        let dev = open_device(entry, instance, debug, validation_log, candidate, &options)?;
        std::mem::forget(debug_guard);
        std::mem::forget(guard);
        Ok(Self { dev: Arc::new(dev) })
    }

    /// What the device offers.
    pub fn info(&self) -> &DeviceInfo {
        &self.dev.info
    }

    /// Validation messages (empty unless the layer is loaded).
    pub fn validation_log(&self) -> Arc<ValidationLog> {
        self.dev.validation_log.clone()
    }

    /// Frees GPU objects whose last use has completed. Called on every
    /// submission and wait; call it yourself only in long idle loops.
    pub fn collect_garbage(&self) {
        self.dev.collect();
    }

    /// How many times the host has blocked on the GPU so far (every
    /// [`crate::gpu::Submission::wait`], every wait for idle): each one is
    /// a CPU–GPU round trip a latency-critical caller pays for.
    pub fn host_waits(&self) -> u64 {
        self.dev.calls.snapshot().host_waits
    }

    /// Submissions, host waits and dispatches so far (see [`GpuCalls`]).
    pub fn gpu_calls(&self) -> GpuCalls {
        self.dev.calls.snapshot()
    }

    /// Blocks until the GPU has finished all submitted work.
    pub fn wait_idle(&self) -> Result<()> {
        self.dev.calls.waited();
        // SAFETY: valid device.
        unsafe { self.dev.raw.device_wait_idle() }.vk("vkDeviceWaitIdle")?;
        self.dev.collect();
        Ok(())
    }
}

/// Destroys a half-built instance on an early return.
struct InstanceGuard(Option<ash::Instance>);
impl Drop for InstanceGuard {
    fn drop(&mut self) {
        if let Some(i) = self.0.take() {
            // SAFETY: only reached when `Device` was never built.
            unsafe { i.destroy_instance(None) };
        }
    }
}
struct DebugGuard(Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>);
impl Drop for DebugGuard {
    fn drop(&mut self) {
        if let Some((du, m)) = self.0.take() {
            // SAFETY: only reached when `Device` was never built.
            unsafe { du.destroy_debug_utils_messenger(m, None) };
        }
    }
}

fn pick_device(instance: &ash::Instance, wanted: Option<&str>) -> Result<Candidate> {
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
                Error::InvalidArgument(format!(
                    "LATENTAM_DEVICE={w} matches no device (available: {})",
                    names()
                ))
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

fn open_device(
    entry: ash::Entry,
    instance: ash::Instance,
    debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    validation_log: Arc<ValidationLog>,
    c: Candidate,
    options: &ContextOptions,
) -> Result<Device> {
    let p = c.physical;
    // SAFETY: queries on a valid physical device.
    let families = unsafe { instance.get_physical_device_queue_family_properties(p) };
    let compute_family = families
        .iter()
        .position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE))
        .ok_or_else(|| Error::Unsupported(format!("{} has no compute queue", c.name)))?
        as u32;
    // A family with transfer but neither graphics nor compute is a DMA engine.
    let transfer_family = families
        .iter()
        .position(|f| {
            f.queue_flags.contains(vk::QueueFlags::TRANSFER)
                && !f.queue_flags.contains(vk::QueueFlags::COMPUTE)
                && !f.queue_flags.contains(vk::QueueFlags::GRAPHICS)
        })
        .map(|i| i as u32);
    let timestamp_valid_bits = families[compute_family as usize].timestamp_valid_bits;

    // SAFETY: valid physical device.
    let exts = unsafe { instance.enumerate_device_extension_properties(p) }
        .vk("vkEnumerateDeviceExtensionProperties")?;
    let has_ext = |name: &CStr| {
        exts.iter()
            .any(|e| e.extension_name_as_c_str().ok() == Some(name))
    };

    let mut atomic_feats = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default();
    let mut v12 = vk::PhysicalDeviceVulkan12Features::default();
    let has_atomic_float_ext = has_ext(ash::ext::shader_atomic_float::NAME);
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
            "{} lacks timeline semaphores (Vulkan 1.2)",
            c.name
        )));
    }
    let native_float_atomics = has_atomic_float_ext
        && atomic_feats.shader_buffer_float32_atomic_add == vk::TRUE
        && options.float_atomics == FloatAtomics::Auto;

    let mut subgroup = vk::PhysicalDeviceSubgroupProperties::default();
    let mut maintenance3 = vk::PhysicalDeviceMaintenance3Properties::default();
    {
        let mut props2 = vk::PhysicalDeviceProperties2::default()
            .push_next(&mut subgroup)
            .push_next(&mut maintenance3);
        // SAFETY: valid chain.
        unsafe { instance.get_physical_device_properties2(p, &mut props2) };
    }

    let priorities = [1.0f32];
    let mut queue_infos = vec![vk::DeviceQueueCreateInfo::default()
        .queue_family_index(compute_family)
        .queue_priorities(&priorities)];
    if let Some(t) = transfer_family {
        queue_infos.push(
            vk::DeviceQueueCreateInfo::default()
                .queue_family_index(t)
                .queue_priorities(&priorities),
        );
    }
    let host_query_reset = v12.host_query_reset == vk::TRUE;
    let mut enable12 = vk::PhysicalDeviceVulkan12Features::default()
        .timeline_semaphore(true)
        .host_query_reset(host_query_reset);
    let mut enable_atomic = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default()
        .shader_buffer_float32_atomic_add(true);
    let mut ext_names: Vec<*const i8> = Vec::new();
    let mut create = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queue_infos)
        .push_next(&mut enable12);
    if native_float_atomics {
        ext_names.push(ash::ext::shader_atomic_float::NAME.as_ptr());
        create = create.push_next(&mut enable_atomic);
    }
    let create = create.enabled_extension_names(&ext_names);
    // SAFETY: valid create info built from queried support.
    let raw = unsafe { instance.create_device(p, &create, None) }.vk("vkCreateDevice")?;

    let make_queue = |family: u32| -> Result<Queue> {
        let mut ti = vk::SemaphoreTypeCreateInfo::default()
            .semaphore_type(vk::SemaphoreType::TIMELINE)
            .initial_value(0);
        let ci = vk::SemaphoreCreateInfo::default().push_next(&mut ti);
        // SAFETY: valid device; destroyed in `Device::drop`.
        let timeline = unsafe { raw.create_semaphore(&ci, None) }.vk("vkCreateSemaphore")?;
        Ok(Queue {
            family,
            // SAFETY: queue index 0 was requested for this family.
            queue: Mutex::new(unsafe { raw.get_device_queue(family, 0) }),
            timeline,
            submitted: AtomicU64::new(0),
            timestamp_bits: families[family as usize].timestamp_valid_bits,
        })
    };
    let compute = match make_queue(compute_family) {
        Ok(q) => q,
        Err(e) => {
            // SAFETY: nothing else created on the device yet.
            unsafe { raw.destroy_device(None) };
            return Err(e);
        }
    };
    let transfer = match transfer_family.map(make_queue).transpose() {
        Ok(t) => t,
        Err(e) => {
            // SAFETY: only the compute semaphore exists.
            unsafe {
                raw.destroy_semaphore(compute.timeline, None);
                raw.destroy_device(None);
            }
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

    let limits = c.props.limits;
    // SAFETY: valid physical device.
    let mem = unsafe { instance.get_physical_device_memory_properties(p) };
    let device_local_bytes = mem.memory_heaps[..mem.memory_heap_count as usize]
        .iter()
        .filter(|h| h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
        .map(|h| h.size)
        .max()
        .unwrap_or(0);
    let timestamp_period_ns = (timestamp_valid_bits > 0).then_some(limits.timestamp_period as f64);
    // Subgroup operations kernels may use: allowed, and supported in compute.
    let subgroup_ops = |ops: vk::SubgroupFeatureFlags| {
        options.subgroup_arithmetic
            && subgroup
                .supported_stages
                .contains(vk::ShaderStageFlags::COMPUTE)
            && subgroup.supported_operations.contains(ops)
    };
    let info = DeviceInfo {
        name: c.name,
        device_type: c.props.device_type,
        api_version: c.props.api_version,
        native_float_atomics,
        subgroup_size: subgroup.subgroup_size,
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
        max_memory_allocation_size: maintenance3
            .max_memory_allocation_size
            .min(options.max_buffer_bytes.unwrap_or(u64::MAX)),
        max_workgroup_count: limits.max_compute_work_group_count,
        max_shared_memory: limits.max_compute_shared_memory_size,
        dedicated_transfer_queue: transfer.is_some(),
        transfer_timestamps: match &transfer {
            Some(t) => t.timestamp_bits > 0 && host_query_reset && timestamp_valid_bits > 0,
            None => timestamp_valid_bits > 0,
        },
        device_local_bytes,
    };
    let profiler = (options.profiling && timestamp_period_ns.is_some())
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
        pipelines: PipelineCache::default(),
        profiler,
        host_query_reset,
        calls: CallCounters::default(),
    })
}
