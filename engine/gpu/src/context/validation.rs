//! The Khronos validation layer's messages: logged, and errors kept for
//! tests to assert on.

use std::ffi::{c_void, CStr};
use std::sync::Mutex;

use ash::vk;

/// The Khronos validation layer's name.
pub(super) const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

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

pub(super) unsafe extern "system" fn debug_callback(
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
