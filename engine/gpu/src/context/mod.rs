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
use latentam_base::{Error, Result, VkContext};

mod open;

use open::*;

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// Whether to load the Khronos validation layer.
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions, Validation};
///
/// let options = ContextOptions { validation: Validation::IfAvailable, ..Default::default() };
/// let ctx = Context::new(options)?;
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
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
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions, FloatAtomics};
///
/// let options = ContextOptions { float_atomics: FloatAtomics::CompareAndSwap, ..Default::default() };
/// let ctx = Context::new(options)?;
/// assert!(!ctx.info().native_float_atomics);
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
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
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions};
///
/// let options = ContextOptions {
///     device: Some("nvidia".into()), // name substring or index
///     memory_budget: Some(4 << 30),
///     ..Default::default()
/// };
/// let ctx = Context::new(options)?;
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
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
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions, Validation};
///
/// let ctx = Context::new(ContextOptions { validation: Validation::Required, ..Default::default() })?;
/// let log = ctx.validation_log();
/// // ... run work ...
/// drop(ctx); // leaks are reported when the device is destroyed
/// assert!(log.errors().is_empty(), "{:?}", log.errors());
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
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
/// let ctx = latentam_gpu::Context::new(Default::default())?;
/// println!("running on {}", ctx.info().name);
/// # Ok::<(), latentam_gpu::Error>(())
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
    /// [`crate::Submission::wait`], every wait for idle): each one is
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
