"""Type stubs of the latentam package (the module is built from Rust)."""

from os import PathLike
from typing import Any, Dict, Iterator, List, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, "PathLike[str]"]
_Matrix = Union[npt.NDArray[np.floating[Any]], Sequence[Sequence[float]]]

class Error(Exception):
    """Base class of latentam's errors (bad arrays and settings raise ValueError subclasses)."""

class BadInputError(ValueError):
    """A value handed in is unusable (an array, a frame, a query, a vocabulary): the message names it and says what is wrong."""

class ConfigError(ValueError):
    """A setting is outside its documented range, settings contradict each other, or the configuration does not parse."""

class NoEmbeddingsError(Error):
    """The map has no embeddings yet: nothing to query."""

class EmbeddingMismatchError(Error):
    """Embeddings of another dimension or model than the map's."""

class DeviceError(Error):
    """No usable Vulkan device, a lost device, or a failed Vulkan call."""

class GpuMemoryError(DeviceError):
    """GPU memory ran out, or the configured budget is too small."""

class BudgetError(GpuMemoryError):
    """A memory budget set by the caller (gpu_budget, the window capacity) is too small for the work asked of it: raise it or ask for less."""

class StoppedError(Error):
    """The mapper stopped (on the error in the message) or was finished."""

class InputError(Error):
    """A log, file or run folder that cannot be read or written."""

class DamagedFileError(InputError):
    """A file is damaged or is not what it claims to be (a checksum that does not match, sizes that disagree, another format or version): use another copy."""

class Snapshot:
    """The map as it stood after one keyframe, as numpy arrays."""

    @property
    def keyframes(self) -> int:
        """Keyframes mapped when it was taken."""
    @property
    def means(self) -> npt.NDArray[np.float32]:
        """Centres [N, 3], world frame, metres."""
    @property
    def scales(self) -> npt.NDArray[np.float32]:
        """Per-axis standard deviations [N, 3], metres."""
    @property
    def rotations(self) -> npt.NDArray[np.float32]:
        """Unit quaternions (w, x, y, z) [N, 4]."""
    @property
    def colors(self) -> npt.NDArray[np.float32]:
        """RGB in 0..1 [N, 3]."""
    @property
    def opacities(self) -> npt.NDArray[np.float32]:
        """Opacities in 0..1 [N]."""
    @property
    def queries(self) -> npt.NDArray[np.float32]:
        """Latent queries [N, 32]."""
    @property
    def keyframe_stamps(self) -> npt.NDArray[np.int64]:
        """Keyframe stamps (ns) [K]."""
    @property
    def keyframe_poses(self) -> npt.NDArray[np.float64]:
        """Keyframe camera-to-world transforms [K, 4, 4]."""
    def query(self, text_embedding: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """Cosine relevance of every Gaussian: [N] for one embedding [D], [N, M] for [M, D]."""
    def __len__(self) -> int: ...

class Mapper:
    """The map, built on a worker thread while Python goes on."""

    def __init__(
        self,
        config: Optional[str] = None,
        queue_frames: int = 8,
        queue_bytes: int = 512 << 20,
        keep_candidates: int = 1,
    ) -> None:
        """A mapper on the first suitable Vulkan device, every kernel compiled.

        config: a TOML string or the path of a TOML file (the keys of
        ``latentam config --print-defaults``), or None for the defaults.
        queue_frames / queue_bytes bound the frames waiting for the worker;
        keep_candidates bounds the keyframe candidates among them (a newer
        one replaces the oldest).
        """
    @staticmethod
    def load(
        dir: _Path,
        queue_frames: int = 8,
        queue_bytes: int = 512 << 20,
        keep_candidates: int = 1,
    ) -> "Mapper":
        """A mapper that goes on with the map saved in the run folder ``dir``."""
    def submit(
        self,
        rgb: npt.NDArray[np.uint8],
        depth: Union[npt.NDArray[np.uint16], npt.NDArray[np.float32]],
        K: _Matrix,
        T_world_camera: _Matrix,
        stamp_ns: int,
        regions: Optional[npt.NDArray[np.uint16]] = None,
        embeddings: Optional[Union[npt.NDArray[np.float16], npt.NDArray[np.float32]]] = None,
        model: str = "unknown",
        wait: bool = False,
    ) -> None:
        """Queues one RGB-D frame and returns at once (with ``wait``: once
        the queue has room, dropping nothing, for recorded data).

        rgb [H, W, 3] uint8; depth [H, W] uint16 millimetres or float32
        metres (0 or NaN: no measurement); K 3×3 pinhole intrinsics;
        T_world_camera a rigid 4×4 camera-to-world transform (camera axes x
        right, y down, z forward); regions [H, W] uint16 region ids (65535:
        none) with embeddings [N, D], one row per id. Frames are dropped by
        policy when the mapper falls behind (``status()["dropped"]``).
        """
    def status(self) -> Dict[str, Any]:
        """Queue depth, frames dropped by reason, latencies (ms), the map's
        Gaussians and GPU bytes after the last keyframe, snapshots taken,
        the last error."""
    def snapshot(self) -> Snapshot:
        """The map after the last keyframe. Snapshots are taken when asked
        for, so this waits at most for the frame being mapped (a map nobody
        reads costs no copies). After ``finish`` or ``abort``, the whole
        final map."""
    def query(self, text_embedding: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """Cosine relevance of every Gaussian of the newest indexed snapshot."""
    def query_names(
        self,
        names: List[str],
        vectors: npt.NDArray[np.float32],
        name: str,
        temperature: float = 0.1,
    ) -> npt.NDArray[np.float32]:
        """Probability per Gaussian that it shows ``name`` rather than another word."""
    def render(
        self, T_world_camera: _Matrix, K: _Matrix, width: int, height: int
    ) -> Dict[str, npt.NDArray[np.float32]]:
        """{"color": [H, W, 3], "depth": [H, W] metres, "alpha": [H, W]} from a pose."""
    def save(self, dir: _Path) -> str:
        """Saves the map into the run folder ``dir``; returns the state file's path."""
    def finish(self) -> None:
        """Maps every queued frame and stops; the map can still be saved."""
    def abort(self) -> None:
        """Stops at once, dropping queued frames; the map can still be saved."""

class LogFrames(Iterator[Dict[str, Any]]):
    """The frames of an MCAP log or rosbag2 folder, as ``Mapper.submit`` keyword arguments."""

    def __init__(self, path: _Path) -> None: ...
    def __iter__(self) -> "LogFrames": ...
    def __next__(self) -> Dict[str, Any]: ...
