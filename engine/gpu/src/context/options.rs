//! How a context is opened: which device, validation, float atomics,
//! subgroups and memory limits, by default from the environment.

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

/// Checks of the validation layer beyond its default ones, when it is on
/// ([`Validation`]); both slow the work down several times, so they are for
/// test runs.
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions, Validation, ValidationChecks};
///
/// let options = ContextOptions {
///     validation: Validation::Required,
///     validation_checks: ValidationChecks { synchronization: true, ..Default::default() },
///     ..Default::default()
/// };
/// let ctx = Context::new(options)?;
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct ValidationChecks {
    /// Synchronization validation: read/write hazards between commands,
    /// batches and queues that a missing or too narrow barrier or
    /// semaphore leaves (a CPU driver, running one command after another,
    /// never shows their effects).
    pub synchronization: bool,
    /// GPU-assisted validation: kernels are instrumented to report
    /// out-of-bounds buffer accesses, which real GPUs punish with garbage
    /// or a lost device.
    pub gpu_assisted: bool,
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

/// Which queue the paging copies (`Context::transfer_recorder`) run on.
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions, TransferQueue};
///
/// // Rehearse the dedicated-transfer-queue path on a device without one.
/// let options = ContextOptions { transfer_queue: TransferQueue::SameFamily, ..Default::default() };
/// let ctx = Context::new(options)?;
/// assert!(ctx.info().dedicated_transfer_queue || ctx.info().transfer_rehearsal);
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum TransferQueue {
    /// A transfer-only queue family when the device has one (discrete
    /// GPUs' copy engines), so paging overlaps compute; else the compute
    /// queue.
    #[default]
    Auto,
    /// Everything on the compute queue.
    Off,
    /// The transfer path on the compute family: a second queue of it when
    /// it offers one, else a second timeline on the compute queue itself.
    /// Paging is recorded and synchronised exactly as for a dedicated
    /// queue (transfer-stage barriers, queries reset from the host,
    /// semaphore waits between the two timelines), so a device without a
    /// transfer family (lavapipe) rehearses that path under validation.
    SameFamily,
}

/// Options for [`Context::new`](crate::Context::new). `Default` reads the environment:
/// `LATENTAM_DEVICE` (index or case-insensitive name substring),
/// `LATENTAM_VALIDATION=1` (require the validation layer),
/// `LATENTAM_VALIDATION_CHECKS=sync,gpu-assisted` (see [`ValidationChecks`]),
/// `LATENTAM_FLOAT_ATOMICS=cas` (force the CAS fallback),
/// `LATENTAM_SUBGROUPS=off` (do not use subgroup arithmetic),
/// `LATENTAM_TRANSFER_QUEUE=off|same-family` (see [`TransferQueue`]),
/// `LATENTAM_MAX_BUFFER_BYTES=N` (cap the largest buffer below the device's),
/// `LATENTAM_REJECT_KERNELS=a,b` (see [`ContextOptions::rejected_kernels`]).
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
    /// The layer's optional checks, when it is on.
    pub validation_checks: ValidationChecks,
    /// Record GPU timestamps around every dispatch.
    pub profiling: bool,
    /// Float-atomic strategy.
    pub float_atomics: FloatAtomics,
    /// Which queue paging copies run on.
    pub transfer_queue: TransferQueue,
    /// GPU memory budget in bytes for this context (`None` = device limits).
    pub memory_budget: Option<u64>,
    /// Use subgroup operations (`subgroupAdd`, shuffles) where the device
    /// supports them in compute shaders; `false` selects kernels that do
    /// without.
    pub subgroup_arithmetic: bool,
    /// Caps the largest buffer the engine creates (the storage-buffer
    /// binding and single-allocation limits of [`DeviceInfo`](crate::DeviceInfo)) below the
    /// device's own: to leave headroom, or to rehearse a device with small
    /// limits (`LATENTAM_MAX_BUFFER_BYTES`). `None`: the device's limits.
    pub max_buffer_bytes: Option<u64>,
    /// Kernels to treat as rejected by the driver's compiler (their
    /// pipeline creation fails with [`Error::KernelBuild`](crate::Error::KernelBuild)
    /// without asking the driver): rehearses a driver that cannot build a
    /// variant, as NVIDIA's cannot build the largest column-layout blending
    /// kernels (`LATENTAM_REJECT_KERNELS`, comma-separated names). Empty:
    /// none.
    pub rejected_kernels: Vec<String>,
    /// Where compiled pipelines are kept between processes, one file per
    /// device, driver and build (`None`: not kept). Default:
    /// `LATENTAM_PIPELINE_CACHE` (`off` for none), else
    /// `$XDG_CACHE_HOME/latentam`, else `$HOME/.cache/latentam`.
    pub pipeline_cache_dir: Option<std::path::PathBuf>,
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
            validation_checks: {
                let checks = env("LATENTAM_VALIDATION_CHECKS").unwrap_or_default();
                let has = |name: &str| checks.split(',').any(|c| c.trim() == name);
                ValidationChecks {
                    synchronization: has("sync"),
                    gpu_assisted: has("gpu-assisted"),
                }
            },
            profiling: false,
            float_atomics: match env("LATENTAM_FLOAT_ATOMICS").as_deref() {
                Some("cas") => FloatAtomics::CompareAndSwap,
                _ => FloatAtomics::Auto,
            },
            transfer_queue: match env("LATENTAM_TRANSFER_QUEUE").as_deref() {
                Some("off") => TransferQueue::Off,
                Some("same-family") => TransferQueue::SameFamily,
                _ => TransferQueue::Auto,
            },
            memory_budget: None,
            subgroup_arithmetic: env("LATENTAM_SUBGROUPS").as_deref() != Some("off"),
            max_buffer_bytes: env("LATENTAM_MAX_BUFFER_BYTES").and_then(|v| v.parse().ok()),
            rejected_kernels: env("LATENTAM_REJECT_KERNELS")
                .map(|v| {
                    v.split(',')
                        .map(str::trim)
                        .filter(|k| !k.is_empty())
                        .map(String::from)
                        .collect()
                })
                .unwrap_or_default(),
            pipeline_cache_dir: crate::pipeline_cache_file::default_dir(),
        }
    }
}
