//! Vulkan instance, device and queue selection; the shared device state that
//! every GPU object holds on to.

use std::ffi::{c_void, CString};
use std::sync::Arc;

use ash::vk;

use super::counters::GpuCalls;
use latentam_base::{Error, Result, VkContext};

mod device;
mod info;
mod open;
mod options;
mod validation;

pub(crate) use device::{Device, Queue};
pub use info::DeviceInfo;
#[cfg(any(test, feature = "testing"))]
pub(crate) use open::QueueFamilies;
use open::*;
pub use options::{ContextOptions, FloatAtomics, TransferQueue, Validation, ValidationChecks};
pub use validation::ValidationLog;
use validation::{debug_callback, VALIDATION_LAYER};

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

/// Whether the instance loads the validation layer, as `validation` asks
/// and the system allows.
fn uses_validation(entry: &ash::Entry, validation: Validation) -> Result<bool> {
    // SAFETY: plain enumeration calls on a loaded entry.
    let layers = unsafe { entry.enumerate_instance_layer_properties() }
        .vk("vkEnumerateInstanceLayerProperties")?;
    let have_validation = layers
        .iter()
        .any(|l| l.layer_name_as_c_str().ok() == Some(VALIDATION_LAYER));
    match validation {
        Validation::Off => Ok(false),
        Validation::IfAvailable => Ok(have_validation),
        Validation::Required if !have_validation => Err(Error::NoVulkan(
            "the Vulkan validation layer VK_LAYER_KHRONOS_validation is required but \
             not installed; on Debian/Ubuntu `sudo apt-get install \
             vulkan-validationlayers`"
                .into(),
        )),
        Validation::Required => Ok(true),
    }
}

/// The validation layer's optional checks `options` turn on.
fn validation_features(options: &ContextOptions) -> Vec<vk::ValidationFeatureEnableEXT> {
    let mut enabled = Vec::new();
    if options.validation_checks.synchronization {
        enabled.push(vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION);
    }
    if options.validation_checks.gpu_assisted {
        enabled.push(vk::ValidationFeatureEnableEXT::GPU_ASSISTED);
        // The instrumentation needs a descriptor set slot of its own.
        enabled.push(vk::ValidationFeatureEnableEXT::GPU_ASSISTED_RESERVE_BINDING_SLOT);
    }
    enabled
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

        let use_validation = uses_validation(&entry, options.validation)?;

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
        let enabled_checks = validation_features(&options);
        let mut features =
            vk::ValidationFeaturesEXT::default().enabled_validation_features(&enabled_checks);
        if use_validation {
            // Also catches errors in instance creation and destruction.
            create = create.push_next(&mut messenger_info);
            if !enabled_checks.is_empty() {
                create = create.push_next(&mut features);
            }
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
        let ctx = Self { dev: Arc::new(dev) };
        ctx.calibrate_host_clock()?;
        Ok(ctx)
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

    /// The work recorded so far: per kernel the arithmetic and bytes its
    /// dispatches need, and the bytes copied between host and device (see
    /// [`crate::GpuWork`]; counted when recorded).
    pub fn gpu_work(&self) -> crate::GpuWork {
        self.dev.work.snapshot()
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
