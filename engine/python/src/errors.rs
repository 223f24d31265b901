//! The engine's errors as Python exceptions: `ValueError` for input that
//! does not fit (arrays, frames, settings), and a `latentam.Error`
//! hierarchy for the rest, each with the engine's message.

use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;

create_exception!(
    latentam,
    Error,
    PyException,
    "Base class of latentam's errors (bad arrays raise ValueError)."
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

/// The Python exception for an engine error.
pub fn to_py(e: latentam::Error) -> PyErr {
    use latentam::Error as E;
    let message = e.to_string();
    match e {
        E::InvalidArgument(_) | E::BadFrame { .. } => PyValueError::new_err(message),
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
    m.add("NoEmbeddingsError", py.get_type::<NoEmbeddingsError>())?;
    m.add(
        "EmbeddingMismatchError",
        py.get_type::<EmbeddingMismatchError>(),
    )?;
    m.add("DeviceError", py.get_type::<DeviceError>())?;
    m.add("GpuMemoryError", py.get_type::<GpuMemoryError>())?;
    m.add("StoppedError", py.get_type::<StoppedError>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    Ok(())
}
