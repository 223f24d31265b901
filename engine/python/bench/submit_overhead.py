"""What the Python binding adds to a frame's submission: `Mapper.submit`
timed from Python on 640×480 frames with 200 regions of 768-d float16
embeddings (checks, one copy of each array into the engine's frame, the
engine's own `submit`), while the mapper maps them. Writes JSON.

    python engine/python/bench/submit_overhead.py --json submit.json

Compare with `submit` in `latentam bench live` (the engine's `submit` from
Rust, same frame size): the difference is the binding's cost.
"""

import argparse
import json
import time

import numpy as np

import latentam


def frame(i: int, rng: np.random.Generator, w: int, h: int, regions: int, dim: int) -> dict:
    labels = (np.arange(h * w, dtype=np.uint32) * regions // (h * w)).astype(np.uint16)
    t = np.eye(4)
    t[0, 3] = 0.01 * i
    return dict(
        rgb=rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
        depth=np.full((h, w), 2000, np.uint16),
        K=np.array([[525.0, 0, w / 2], [0, 525.0, h / 2], [0, 0, 1]]),
        T_world_camera=t,
        stamp_ns=i * 33_333_333,
        regions=labels.reshape(h, w),
        embeddings=rng.standard_normal((regions, dim)).astype(np.float16),
        model="synthetic",
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--regions", type=int, default=200)
    p.add_argument("--dim", type=int, default=768)
    p.add_argument("--json")
    a = p.parse_args()
    rng = np.random.default_rng(0)
    frames = [frame(i, rng, a.width, a.height, a.regions, a.dim) for i in range(16)]
    mapper = latentam.Mapper()
    ms = []
    for i in range(a.frames):
        f = dict(frames[i % len(frames)], stamp_ns=i * 33_333_333)
        t = time.perf_counter()
        mapper.submit(**f)
        ms.append((time.perf_counter() - t) * 1e3)
        time.sleep(1 / 30)
    mapper.abort()
    ms.sort()
    at = lambda q: ms[min(len(ms) - 1, int(q * len(ms)))]  # noqa: E731
    report = dict(
        frames=a.frames, width=a.width, height=a.height, regions=a.regions, dim=a.dim,
        submit_p50_ms=at(0.5), submit_p99_ms=at(0.99), submit_max_ms=ms[-1],
    )
    print(json.dumps(report, indent=1))
    if a.json:
        with open(a.json, "w") as out:
            json.dump(report, out, indent=1)


if __name__ == "__main__":
    main()
