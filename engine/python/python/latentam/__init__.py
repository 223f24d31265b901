"""latentam: online latent 3D Gaussian mapping (LatentAM) on Vulkan compute.

A ``Mapper`` maps on a worker thread: ``submit`` only enqueues a frame and
returns, while any thread reads snapshots of the map and asks which
Gaussians match a text embedding. Every array is checked (shape, dtype,
finite values, a rigid pose) and a misfit raises ``ValueError``; the
engine's other failures raise subclasses of ``latentam.Error``. The GIL is
released while the engine works.

    import latentam
    mapper = latentam.Mapper()
    for frame in latentam.LogFrames("scene.mcap"):
        mapper.submit(**frame)
    scores = mapper.query(text_embedding)  # one relevance per Gaussian
    mapper.finish()
    mapper.save("run/")
"""

from ._latentam import (
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
