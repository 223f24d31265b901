"""latentam: online latent 3D Gaussian mapping (LatentAM) on Vulkan compute.

A ``Mapper`` maps on a worker thread: ``submit`` only enqueues a frame and
returns, while any thread reads snapshots of the map and asks which
Gaussians match a text embedding. Every array is checked (shape, dtype,
finite values, a rigid pose) and a misfit raises ``BadInputError``, a
setting out of range ``ConfigError`` (both ``ValueError`` subclasses); the
engine's other failures raise subclasses of ``latentam.Error``:
``BudgetError`` (a ``GpuMemoryError``) when a memory budget set is too
small, ``DamagedFileError`` (an ``InputError``) for a damaged file. The GIL
is released while the engine works.

    import latentam
    mapper = latentam.Mapper()
    for frame in latentam.LogFrames("scene.mcap"):
        mapper.submit(**frame)
    scores = mapper.query(text_embedding)  # one relevance per Gaussian
    mapper.finish()
    mapper.save("run/")
"""

from ._latentam import (
    BadInputError,
    BudgetError,
    ConfigError,
    DamagedFileError,
    DeviceError,
    EmbeddingMismatchError,
    Error,
    GpuMemoryError,
    InputError,
    LogFrames,
    Mapper,
    NoEmbeddingsError,
    Snapshot,
    StoppedError,
)

__all__ = [
    "BadInputError",
    "BudgetError",
    "ConfigError",
    "DamagedFileError",
    "DeviceError",
    "EmbeddingMismatchError",
    "Error",
    "GpuMemoryError",
    "InputError",
    "LogFrames",
    "Mapper",
    "NoEmbeddingsError",
    "Snapshot",
    "StoppedError",
]
