//! The library's error type.

use std::fmt;
use std::path::PathBuf;

use ash::vk;

/// Everything that can go wrong inside the engine, with enough context to
/// tell the user what to change. A program tells what to do from the
/// kind, not the words: fix what it passed ([`Error::BadInput`]), fix a
/// setting ([`Error::Config`]), raise a budget ([`Error::Budget`]), use
/// another copy of a file ([`Error::Damaged`]).
///
/// ```
/// use latentam_base::Error;
///
/// fn advice(e: &Error) -> &'static str {
///     match e {
///         Error::NoVulkan(_) => "install a Vulkan driver (mesa-vulkan-drivers)",
///         Error::OutOfMemory(_) => "lower gpu_budget or the image size",
///         Error::Budget { .. } => "raise the budget it names",
///         Error::Config { .. } => "fix the setting it names",
///         Error::Damaged { .. } => "use another copy of the file",
///         Error::BadInput { .. } => "fix the input it names",
///         Error::Locked { .. } => "wait for the other process or pick another folder",
///         _ => "see the message",
///     }
/// }
/// assert_eq!(advice(&Error::OutOfMemory("window".into())), "lower gpu_budget or the image size");
/// assert_eq!(advice(&Error::config("voxel_size", "-1 must be from 0.0001 to 1 metres")), "fix the setting it names");
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
    /// The driver could not build one of the engine's kernels (its
    /// compiler rejected or failed on the SPIR-V). Names the kernel, so a
    /// report says which one; the same error on every device of a vendor
    /// is a bug in the engine or the driver, worth reporting either way.
    #[error("the driver could not build kernel `{kernel}`: {result}")]
    KernelBuild {
        /// The kernel (the generated table's name, e.g. `raster_backward_cas`).
        kernel: &'static str,
        /// The result of vkCreateComputePipelines or vkCreateShaderModule.
        result: vk::Result,
    },
    /// The GPU device was lost (a driver reset, a hung or faulted
    /// kernel, a removed GPU): nothing on it can be used again. A map
    /// loses at most what it did since its last save.
    #[error("the GPU device was lost in {call}; reload the last save on a new context")]
    DeviceLost {
        /// The Vulkan entry point that reported it.
        call: &'static str,
    },
    /// GPU memory could not be allocated (device memory exhausted or the
    /// configured budget reached).
    #[error("GPU memory: {0}")]
    OutOfMemory(String),
    /// A value handed in is unusable: an argument of a call, a field of a
    /// frame, a query, a vocabulary, a command-line value. Names the input
    /// and says what is wrong with it; the caller fixes what it passed.
    #[error("{what}: {reason}")]
    BadInput {
        /// The input (an argument, a field, a file's entry).
        what: String,
        /// What is wrong with it.
        reason: String,
    },
    /// A setting is outside its documented range, or settings contradict
    /// each other (a TOML file that does not parse is this too); the
    /// caller fixes the setting.
    #[error("setting `{setting}`: {reason}")]
    Config {
        /// The setting (its dotted key, e.g. `window.capacity`), or the
        /// configuration as a whole.
        setting: String,
        /// What is wrong with it.
        reason: String,
    },
    /// A memory budget the caller set (`gpu_budget`, a window capacity...)
    /// is too small for the work asked of it: raise it or ask for less.
    #[error("{budget} is too small: {reason}")]
    Budget {
        /// The budget (the setting or argument that sets it).
        budget: String,
        /// What it would have to hold.
        reason: String,
    },
    /// A file is damaged or is not what it claims to be (a checksum that
    /// does not match, sizes that do not agree, another format or
    /// version): use another copy.
    #[error("{}: {reason}", path.display())]
    Damaged {
        /// The file (or folder).
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// The map has no embeddings yet (no keyframe with region embeddings
    /// has been mapped), so there is nothing to score a query against.
    #[error("the map has no embeddings yet: nothing to query")]
    NoEmbeddings,
    /// Embeddings of another dimension than the map's.
    #[error("{given}-d embeddings{}, the map's are {map}-d", context.as_deref().map_or(String::new(), |c| format!(" ({c})")))]
    EmbeddingDimension {
        /// The map's embedding dimension d_f.
        map: u32,
        /// The dimension given.
        given: u32,
        /// What carried them (a frame, a vocabulary, a query), if known.
        context: Option<String>,
    },
    /// Embeddings from another model than the map's: their spaces differ,
    /// so mixing them would mean nothing.
    #[error("embeddings of model `{given}`{}, the map's are of `{map}`", context.as_deref().map_or(String::new(), |c| format!(" ({c})")))]
    EmbeddingModel {
        /// The model of the map's region embeddings.
        map: String,
        /// The model given.
        given: String,
        /// What carried them (a frame, a vocabulary), if known.
        context: Option<String>,
    },
    /// A frame the map cannot take (a pose that is no rigid transform,
    /// intrinsics that are no pinhole camera); the map is unchanged.
    #[error("frame at {stamp_ns} ns: {reason}")]
    BadFrame {
        /// The frame's stamp.
        stamp_ns: i64,
        /// What is wrong with it.
        reason: String,
    },
    /// A live mapper's worker stopped on this error: the map is kept as
    /// it was before the failed keyframe began only if the error says so
    /// (see `LiveMapper`); the handle refuses further frames.
    #[error("the mapper stopped: {0}")]
    Stopped(std::sync::Arc<Error>),
    /// The mapping worker panicked (a bug in the engine: please report it
    /// with the message).
    #[error("the mapping worker panicked: {0}")]
    Panicked(String),
    /// The device lacks a feature or limit the engine needs.
    #[error("unsupported device: {0}")]
    Unsupported(String),
    /// An input log or one of its messages is unusable.
    #[error(transparent)]
    Input(#[from] InputError),
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

impl Error {
    /// [`Error::BadInput`]: `what` is unusable because of `reason`.
    ///
    /// ```
    /// use latentam_base::Error;
    ///
    /// let e = Error::bad_input("query", "empty");
    /// assert_eq!(e.to_string(), "query: empty");
    /// assert!(matches!(e, Error::BadInput { .. }));
    /// ```
    pub fn bad_input(what: impl Into<String>, reason: impl Into<String>) -> Self {
        Error::BadInput {
            what: what.into(),
            reason: reason.into(),
        }
    }

    /// [`Error::Config`]: `setting` is out of range because of `reason`.
    ///
    /// ```
    /// use latentam_base::Error;
    ///
    /// let e = Error::config("window.capacity", "must be at least 1");
    /// assert_eq!(e.to_string(), "setting `window.capacity`: must be at least 1");
    /// ```
    pub fn config(setting: impl Into<String>, reason: impl Into<String>) -> Self {
        Error::Config {
            setting: setting.into(),
            reason: reason.into(),
        }
    }

    /// [`Error::Budget`]: `budget` cannot hold what `reason` says.
    ///
    /// ```
    /// use latentam_base::Error;
    ///
    /// let e = Error::budget("gpu_budget", "the window needs 2 GiB");
    /// assert_eq!(e.to_string(), "gpu_budget is too small: the window needs 2 GiB");
    /// ```
    pub fn budget(budget: impl Into<String>, reason: impl Into<String>) -> Self {
        Error::Budget {
            budget: budget.into(),
            reason: reason.into(),
        }
    }

    /// [`Error::Damaged`]: the file at `path` is damaged, because of
    /// `reason`.
    ///
    /// ```
    /// use latentam_base::Error;
    ///
    /// let e = Error::damaged("run/map.safetensors", "checksum mismatch");
    /// assert_eq!(e.to_string(), "run/map.safetensors: checksum mismatch");
    /// ```
    pub fn damaged(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::Damaged {
            path: path.into(),
            reason: reason.into(),
        }
    }
}

/// What went wrong reading or writing a log.
///
/// ```
/// use latentam_base::{Error, InputError};
///
/// let e = InputError::Topic { topic: "/camera/depth".into(), reason: "not in the log".into() };
/// assert_eq!(e.to_string(), "topic /camera/depth: not in the log");
/// let e: Error = e.into(); // the engine's error wraps it unchanged
/// assert!(matches!(e, Error::Input(InputError::Topic { .. })));
/// ```
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    /// The file system refused.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// What the OS said.
        #[source]
        source: std::io::Error,
    },
    /// The MCAP structure is damaged (truncated, corrupt chunk, bad
    /// record).
    #[error("{path}: {reason}")]
    Log {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A topic the configuration needs is missing or has the wrong type.
    #[error("topic {topic}: {reason}")]
    Topic {
        /// The topic(s).
        topic: String,
        /// What is wrong.
        reason: String,
    },
    /// A message or frame was rejected under `BadInputPolicy::Stop`.
    #[error("{topic} at stamp {stamp_ns} ns: {rejection}")]
    Rejected {
        /// The topic of the message (the colour topic for whole frames).
        topic: String,
        /// Its stamp (log time for undecodable messages).
        stamp_ns: i64,
        /// Why.
        rejection: Rejection,
    },
    /// Writing a log failed.
    #[error("writing MCAP: {0}")]
    Write(String),
}

/// Why one message or frame was not used.
///
/// ```
/// use latentam_base::Rejection;
///
/// let why = Rejection::new("depth: size mismatch", "depth 320×240, colour 640×480");
/// assert_eq!(why.to_string(), "depth: size mismatch: depth 320×240, colour 640×480");
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Rejection {
    /// A stable short reason, `"stream: what"`, the key counts are kept by.
    pub kind: &'static str,
    /// The specifics of this instance (sizes, values, stamps).
    pub detail: String,
}

impl Rejection {
    /// A rejection of kind `kind`.
    pub fn new(kind: &'static str, detail: impl Into<String>) -> Self {
        Rejection {
            kind,
            detail: detail.into(),
        }
    }
}

impl fmt::Display for Rejection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.kind, self.detail)
    }
}

impl std::error::Error for Rejection {}

/// Result alias used throughout the engine.
///
/// ```
/// use latentam_base::{Camera, Result};
///
/// fn pixels(cams: &[Camera]) -> Result<u64> {
///     cams.iter().map(|c| c.validate().map(|()| c.pixels())).sum()
/// }
/// assert_eq!(pixels(&[Camera::at_origin(4, 4); 2])?, 32);
/// # Ok::<(), latentam_base::Error>(())
/// ```
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Attaches the Vulkan entry point name to an `ash` result.
#[doc(hidden)]
pub trait VkContext<T> {
    /// The result as the engine's error, naming `call`.
    fn vk(self, call: &'static str) -> Result<T>;
}

impl<T> VkContext<T> for std::result::Result<T, vk::Result> {
    fn vk(self, call: &'static str) -> Result<T> {
        self.map_err(|result| match result {
            vk::Result::ERROR_OUT_OF_DEVICE_MEMORY | vk::Result::ERROR_OUT_OF_HOST_MEMORY => {
                Error::OutOfMemory(format!("{call}: {result}"))
            }
            vk::Result::ERROR_DEVICE_LOST => Error::DeviceLost { call },
            _ => Error::Vulkan { call, result },
        })
    }
}
