//! The engine's errors as Python exceptions, one class per kind a caller
//! acts on, each with the engine's message: `BadInputError` and
//! `ConfigError` (both `ValueError`s) for input and settings that do not
//! fit, and a `latentam.Error` hierarchy for the rest (`BudgetError` under
//! `GpuMemoryError`, `DamagedFileError` under `InputError`).

use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;

create_exception!(
    latentam,
    Error,
    PyException,
    "Base class of latentam's errors (bad arrays and settings raise ValueError subclasses)."
);
create_exception!(
    latentam,
    BadInputError,
    PyValueError,
    "A value handed in is unusable (an array, a frame, a query, a vocabulary): \
     the message names it and says what is wrong."
);
create_exception!(
    latentam,
    ConfigError,
    PyValueError,
    "A setting is outside its documented range, settings contradict each other, \
     or the configuration does not parse."
);
create_exception!(
    latentam,
    NoEmbeddingsError,
    Error,
    "The map has no embeddings yet: nothing to query."
);
create_exception!(
    latentam,
    EmbeddingMismatchError,
    Error,
    "Embeddings of another dimension or model than the map's."
);
create_exception!(
    latentam,
    DeviceError,
    Error,
    "No usable Vulkan device, a lost device, or a failed Vulkan call."
);
create_exception!(
    latentam,
    GpuMemoryError,
    DeviceError,
    "GPU memory ran out, or the configured budget is too small."
);
create_exception!(
    latentam,
    BudgetError,
    GpuMemoryError,
    "A memory budget set by the caller (gpu_budget, the window capacity) is too \
     small for the work asked of it: raise it or ask for less."
);
create_exception!(
    latentam,
    StoppedError,
    Error,
    "The mapper stopped (on the error in the message) or was finished."
);
create_exception!(
    latentam,
    InputError,
    Error,
    "A log, file or run folder that cannot be read or written."
);
create_exception!(
    latentam,
    DamagedFileError,
    InputError,
    "A file is damaged or is not what it claims to be (a checksum that does not \
     match, sizes that disagree, another format or version): use another copy."
);

/// The Python exception for an engine error.
pub fn to_py(e: latentam::Error) -> PyErr {
    use latentam::Error as E;
    let message = e.to_string();
    match e {
        E::BadInput { .. } | E::BadFrame { .. } => BadInputError::new_err(message),
        E::Config { .. } => ConfigError::new_err(message),
        E::Budget { .. } => BudgetError::new_err(message),
        E::Damaged { .. } => DamagedFileError::new_err(message),
        E::NoEmbeddings => NoEmbeddingsError::new_err(message),
        E::EmbeddingDimension { .. } | E::EmbeddingModel { .. } => {
            EmbeddingMismatchError::new_err(message)
        }
        E::OutOfMemory(_) => GpuMemoryError::new_err(message),
        E::NoVulkan(_)
        | E::Vulkan { .. }
        | E::KernelBuild { .. }
        | E::DeviceLost { .. }
        | E::Unsupported(_) => DeviceError::new_err(message),
        E::Stopped(_) => StoppedError::new_err(message),
        E::Input(_) | E::Io { .. } | E::Locked { .. } => InputError::new_err(message),
        _ => Error::new_err(message),
    }
}

/// Adds the exception classes to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("Error", py.get_type::<Error>())?;
    m.add("BadInputError", py.get_type::<BadInputError>())?;
    m.add("ConfigError", py.get_type::<ConfigError>())?;
    m.add("NoEmbeddingsError", py.get_type::<NoEmbeddingsError>())?;
    m.add(
        "EmbeddingMismatchError",
        py.get_type::<EmbeddingMismatchError>(),
    )?;
    m.add("DeviceError", py.get_type::<DeviceError>())?;
    m.add("GpuMemoryError", py.get_type::<GpuMemoryError>())?;
    m.add("BudgetError", py.get_type::<BudgetError>())?;
    m.add("StoppedError", py.get_type::<StoppedError>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("DamagedFileError", py.get_type::<DamagedFileError>())?;
    Ok(())
}
