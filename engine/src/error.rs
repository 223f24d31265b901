//! The library's error type.

use ash::vk;

/// Everything that can go wrong inside the engine, with enough context to
/// tell the user what to change.
///
/// ```no_run
/// use latentam::gpu::{Context, ContextOptions};
/// use latentam::Error;
///
/// match Context::new(ContextOptions::default()) {
///     Ok(ctx) => println!("mapping on {}", ctx.info().name),
///     Err(Error::NoVulkan(hint)) => eprintln!("no Vulkan driver: {hint}"),
///     Err(e) => return Err(e),
/// }
/// # Ok::<(), latentam::Error>(())
/// ```
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// No Vulkan loader or no Vulkan device on this machine.
    #[error("{0}")]
    NoVulkan(String),
    /// A Vulkan call failed.
    #[error("Vulkan call {call} failed: {result}")]
    Vulkan {
        /// The Vulkan entry point that failed.
        call: &'static str,
        /// Its result code.
        result: vk::Result,
    },
    /// GPU memory could not be allocated (device memory exhausted or the
    /// configured budget reached).
    #[error("GPU memory: {0}")]
    OutOfMemory(String),
    /// An argument is outside what the operation supports.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// The device lacks a feature or limit the engine needs.
    #[error("unsupported device: {0}")]
    Unsupported(String),
    /// An input log or one of its messages is unusable.
    #[error(transparent)]
    Input(#[from] crate::io::InputError),
    /// Another process is writing the run folder.
    #[error(
        "{} is being written by another latentam process{}; wait for it to end or choose another folder",
        path.display(),
        pid.map_or(String::new(), |p| format!(" (pid {p})"))
    )]
    Locked {
        /// The run folder.
        path: std::path::PathBuf,
        /// The writer's process id, when its lock file says.
        pid: Option<u32>,
    },
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// What the OS said.
        #[source]
        source: std::io::Error,
    },
}

/// Result alias used throughout the engine.
///
/// ```
/// use latentam::splat::{BatchLayout, Camera};
///
/// fn batch_pixels(cams: &[Camera]) -> latentam::Result<u64> {
///     Ok(BatchLayout::for_cameras(cams)?.pixels)
/// }
/// assert_eq!(batch_pixels(&[Camera::at_origin(4, 4); 2])?, 32);
/// # Ok::<(), latentam::Error>(())
/// ```
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Attaches the Vulkan entry point name to an `ash` result.
pub(crate) trait VkContext<T> {
    fn vk(self, call: &'static str) -> Result<T>;
}

impl<T> VkContext<T> for std::result::Result<T, vk::Result> {
    fn vk(self, call: &'static str) -> Result<T> {
        self.map_err(|result| match result {
            vk::Result::ERROR_OUT_OF_DEVICE_MEMORY | vk::Result::ERROR_OUT_OF_HOST_MEMORY => {
                Error::OutOfMemory(format!("{call}: {result}"))
            }
            _ => Error::Vulkan { call, result },
        })
    }
}
