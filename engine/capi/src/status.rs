//! What every call returns ([`LatentamStatus`]), the message of the
//! last failure on the thread, and the checks that turn a panic, an
//! engine error or a bad string argument into a status.

use std::cell::RefCell;
use std::ffi::{c_char, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};

/// What a call did.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LatentamStatus {
    /// It worked.
    Ok = 0,
    /// A NULL, freed or unknown handle.
    InvalidHandle = 1,
    /// An argument that is unusable (out of range, of the wrong size), or a
    /// NULL pointer where one is needed: fix what was passed.
    InvalidArgument = 2,
    /// A frame that does not hold together (sizes, pose, intrinsics).
    BadFrame = 3,
    /// The map has no embeddings yet: nothing to query.
    NoEmbeddings = 4,
    /// Embeddings of another dimension or model than the map's.
    EmbeddingMismatch = 5,
    /// No usable Vulkan device, a lost device, a failed Vulkan call.
    Device = 6,
    /// GPU memory ran out (the device's, or `gpu_budget` reached by an
    /// allocation).
    GpuMemory = 7,
    /// The mapper stopped (on the error in the message) or was finished.
    Stopped = 8,
    /// A file, log or run folder that cannot be read or written.
    Io = 9,
    /// The output buffer is too small; the count needed was written.
    BufferTooSmall = 10,
    /// The log has no more frames.
    EndOfLog = 11,
    /// A bug in the engine (a caught panic): please report the message.
    Internal = 12,
    /// The queue stayed full for the time given; the frame was not queued.
    Busy = 13,
    /// A setting outside its documented range, settings that contradict
    /// each other, or a configuration that does not parse: fix the setting
    /// the message names.
    Config = 14,
    /// A file that is damaged or not what it claims to be (a checksum that
    /// does not match, another format or version): use another copy.
    Damaged = 15,
    /// A memory budget the caller set (`gpu_budget`, the window capacity)
    /// is too small for the work asked of it: raise it or ask for less.
    Budget = 16,
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

/// The message of the last failed call on this thread ("" after none);
/// valid until the next failed call on this thread.
#[no_mangle]
pub extern "C" fn latentam_last_error_message() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

pub(crate) fn fail(status: LatentamStatus, message: impl Into<String>) -> LatentamStatus {
    let text = message.into().replace('\0', " ");
    LAST_ERROR.with(|e| *e.borrow_mut() = CString::new(text).unwrap_or_default());
    status
}

pub(crate) fn engine_error(e: latentam::Error) -> LatentamStatus {
    use latentam::Error as E;
    let status = match &e {
        E::BadInput { .. } => LatentamStatus::InvalidArgument,
        E::Config { .. } => LatentamStatus::Config,
        E::Damaged { .. } => LatentamStatus::Damaged,
        E::Budget { .. } => LatentamStatus::Budget,
        E::BadFrame { .. } => LatentamStatus::BadFrame,
        E::NoEmbeddings => LatentamStatus::NoEmbeddings,
        E::EmbeddingDimension { .. } | E::EmbeddingModel { .. } => {
            LatentamStatus::EmbeddingMismatch
        }
        E::OutOfMemory(_) => LatentamStatus::GpuMemory,
        E::NoVulkan(_)
        | E::Vulkan { .. }
        | E::KernelBuild { .. }
        | E::DeviceLost { .. }
        | E::Unsupported(_) => LatentamStatus::Device,
        E::Stopped(_) => LatentamStatus::Stopped,
        E::Input(_) | E::Io { .. } | E::Locked { .. } => LatentamStatus::Io,
        _ => LatentamStatus::Internal,
    };
    fail(status, e.to_string())
}

/// Runs `f`, turning a panic into [`LatentamStatus::Internal`].
pub(crate) fn guard(f: impl FnOnce() -> LatentamStatus) -> LatentamStatus {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(status) => status,
        Err(p) => {
            let m = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            fail(LatentamStatus::Internal, format!("latentam panicked: {m}"))
        }
    }
}

/// A C string argument, or an error for NULL or invalid UTF-8.
pub(crate) unsafe fn text<'a>(p: *const c_char, what: &str) -> Result<&'a str, LatentamStatus> {
    if p.is_null() {
        return Err(fail(
            LatentamStatus::InvalidArgument,
            format!("{what} is NULL"),
        ));
    }
    // SAFETY: the caller passes a NUL-terminated string.
    unsafe { CStr::from_ptr(p) }.to_str().map_err(|_| {
        fail(
            LatentamStatus::InvalidArgument,
            format!("{what} is not UTF-8"),
        )
    })
}
