"""Maps a folder of RGB-D frames in the 7-Scenes layout through the Python
package, with numpy and Pillow, while a second thread reads the map as it
grows; saves a run folder that `latentam eval`, `query` and `export` read.

    python engine/python/examples/map_folder.py ../shared/data/7scenes-redkitchen run/ --frames 60

The layout: `frame-XXXXXX.color.jpg` (RGB), `frame-XXXXXX.depth.png`
(uint16 millimetres, 0 = none), `frame-XXXXXX.pose.txt` (4×4
camera-to-world, OpenCV camera axes) and `camera-intrinsics.txt` (3×3).
Depth is used as recorded, with the intrinsics given (what `latentam
convert 7scenes --no-registration` does); frames get stamps `--fps` apart.
"""

import argparse
import pathlib
import threading
import time

import numpy as np
from PIL import Image

import latentam


def read_frames(folder: pathlib.Path, limit: int, fps: float):
    """The folder's frames as `Mapper.submit` keyword arguments."""
    K = np.loadtxt(folder / "camera-intrinsics.txt")
    colours = sorted(folder.glob("frame-*.color.jpg"))[:limit]
    if not colours:
        raise SystemExit(f"{folder}: no frame-*.color.jpg")
    for i, colour in enumerate(colours):
        stem = colour.name[: -len(".color.jpg")]
        yield dict(
            rgb=np.asarray(Image.open(colour).convert("RGB"), dtype=np.uint8),
            depth=np.asarray(Image.open(folder / f"{stem}.depth.png"), dtype=np.uint16),
            K=K,
            T_world_camera=np.loadtxt(folder / f"{stem}.pose.txt"),
            stamp_ns=round(i * 1e9 / fps),
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=pathlib.Path)
    parser.add_argument("out", type=pathlib.Path)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--fps", type=float, default=30.0)
    args = parser.parse_args()

    mapper = latentam.Mapper()
    done = threading.Event()

    def watch() -> None:
        # Reads the map while it is built: a snapshot waits at most for the
        # frame being mapped.
        while not done.wait(1.0):
            s = mapper.snapshot()
            if len(s):
                lo, hi = s.means.min(axis=0), s.means.max(axis=0)
                print(f"keyframe {s.keyframes}: {len(s)} Gaussians in {np.round(hi - lo, 2)} m", flush=True)

    watcher = threading.Thread(target=watch)
    watcher.start()
    start = time.monotonic()
    frames = 0
    for frame in read_frames(args.folder, args.frames, args.fps):
        mapper.submit(**frame, wait=True)  # a recording: keep every frame
        frames += 1
    mapper.finish()
    done.set()
    watcher.join()
    state = mapper.save(args.out)
    print(f"{frames} frames in {time.monotonic() - start:.1f} s; saved {state}")


if __name__ == "__main__":
    main()
