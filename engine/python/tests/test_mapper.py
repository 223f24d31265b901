"""The Python package on the generated scene (lavapipe): mapping through
the binding gives the map `latentam map` gives, queries run from a second
thread while frames are submitted, the GIL is released while the engine
works, and misuse raises the right exception with a clear message."""

import json
import threading
import time

import numpy as np
import pytest

import latentam
from conftest import run

# Room for every frame: nothing is dropped, so the map is comparable.
NO_DROPS = dict(queue_frames=64, keep_candidates=64)


def frames_of(log):
    return list(latentam.LogFrames(str(log)))


def psnr(run_dir, log, tmp_path):
    report = tmp_path / f"eval-{run_dir.name}.json"
    run("eval", str(run_dir), str(log), "--every", "8", "--offset", "2", "--json", str(report))
    return json.loads(report.read_text())["mean"]["psnr"]


def test_the_binding_maps_as_latentam_map_does(scene, tmp_path):
    mapper = latentam.Mapper(**NO_DROPS)
    for frame in frames_of(scene):
        mapper.submit(**frame)
    mapper.finish()
    mapper.save(tmp_path / "python")
    run("map", str(scene), "--out", str(tmp_path / "cli"))

    ours = latentam.Mapper.load(tmp_path / "python").snapshot()
    theirs = latentam.Mapper.load(tmp_path / "cli").snapshot()
    assert ours.keyframes == theirs.keyframes == 6
    # Float rounding differs between runs (atomic adds); the map does not.
    assert abs(len(ours) - len(theirs)) <= len(theirs) // 200, (len(ours), len(theirs))
    a, b = psnr(tmp_path / "python", scene, tmp_path), psnr(tmp_path / "cli", scene, tmp_path)
    assert abs(a - b) < 0.1, (a, b)
    # What `latentam query` reads.
    run("query", str(tmp_path / "python"), "--name", "chair", "--vocabulary", str(scene))


def test_queries_run_beside_submission(scene):
    frames = frames_of(scene)
    mapper = latentam.Mapper(**NO_DROPS)
    stop = threading.Event()
    answers, errors = [], []

    def ask():
        text = np.random.default_rng(1).standard_normal(64).astype(np.float32)
        while not stop.is_set():
            try:
                scores = mapper.query(text)
                snapshot = mapper.snapshot()
                assert scores.ndim == 1 and scores.dtype == np.float32
                answers.append((len(scores), len(snapshot)))
            except latentam.NoEmbeddingsError:
                pass
            except Exception as e:  # noqa: BLE001 - reported below
                errors.append(e)
            time.sleep(0.01)

    asker = threading.Thread(target=ask)
    asker.start()
    for frame in frames:
        mapper.submit(**frame)
        time.sleep(0.02)
    while mapper.status()["integrated"] < len(frames):
        time.sleep(0.05)
    stop.set()
    asker.join(timeout=60)
    mapper.finish()
    assert not asker.is_alive(), "the query thread is stuck"
    assert not errors, errors
    assert answers, "no query was answered while mapping"


def test_the_gil_is_released_while_the_engine_works(scene):
    mapper = latentam.Mapper(**NO_DROPS)
    for frame in frames_of(scene):
        mapper.submit(**frame)
    count = [0]
    stop = threading.Event()

    def counter():
        while not stop.is_set():
            count[0] += 1

    t = threading.Thread(target=counter)
    t.start()
    time.sleep(0.05)
    before = count[0]
    start = time.monotonic()
    mapper.finish()  # maps the queued frames: seconds of engine work
    took = time.monotonic() - start
    after = count[0]
    stop.set()
    t.join()
    assert took > 0.2
    # A counter that ran through finish() counted far more than it does
    # in the few switches a held GIL would allow.
    assert after - before > 10_000, (after - before, took)


def test_snapshots_queries_and_renders(scene):
    frames = frames_of(scene)
    mapper = latentam.Mapper(**NO_DROPS)
    for frame in frames:
        mapper.submit(**frame)
    while mapper.status()["integrated"] < len(frames):
        time.sleep(0.05)
    # Nobody read the map while it was mapped: no copy of it was taken.
    status = mapper.status()
    assert status["snapshots"] == 0, status
    s = mapper.snapshot()
    n = len(s)
    assert n > 0 and s.keyframes == 6
    assert n == status["gaussians"] and mapper.status()["snapshots"] == 1
    assert s.means.shape == (n, 3) and s.means.dtype == np.float32
    assert s.scales.shape == (n, 3) and (s.scales > 0).all()
    assert s.rotations.shape == (n, 4)
    assert np.allclose(np.linalg.norm(s.rotations, axis=1), 1.0, atol=1e-3)
    assert s.colors.shape == (n, 3) and s.opacities.shape == (n,)
    assert ((s.opacities > 0) & (s.opacities < 1)).all()
    assert s.queries.shape == (n, 32)
    assert s.keyframe_poses.shape == (6, 4, 4) and s.keyframe_stamps.shape == (6,)
    f = frames[0]
    assert np.allclose(s.keyframe_poses[0], f["T_world_camera"], atol=1e-6)

    texts = np.random.default_rng(2).standard_normal((3, 64)).astype(np.float32)
    many = mapper.query(texts)
    assert many.shape == (n, 3)
    one = mapper.query(texts[1])
    assert np.allclose(one, many[:, 1], atol=1e-6)
    assert np.allclose(s.query(texts[1]), one, atol=1e-6)
    assert (np.abs(one) <= 1.0 + 1e-5).all()
    names = ["a", "b", "c"]
    p = mapper.query_names(names, texts, "b", temperature=0.1)
    assert p.shape == (n,) and ((p >= 0) & (p <= 1)).all()

    h, w = f["rgb"].shape[:2]
    view = mapper.render(f["T_world_camera"], f["K"], w, h)
    assert view["color"].shape == (h, w, 3) and view["depth"].shape == (h, w)
    assert view["alpha"].max() > 0.5
    mapper.finish()
    # After finishing, the snapshot is the final map: the same Gaussians
    # (in the map's order, which paging may have changed), keyframes and
    # relevance.
    final = mapper.snapshot()
    assert len(final) == n and final.keyframes == 6
    before, after = np.lexsort(s.means.T), np.lexsort(final.means.T)
    assert np.array_equal(final.means[after], s.means[before])
    assert np.allclose(final.query(texts[1])[after], one[before], atol=1e-6)


def base_frame(scene):
    return dict(frames_of(scene)[0])


def with_(frame, **changes):
    f = dict(frame)
    f.update(changes)
    return f


def misuse_cases(f):
    h, w = f["rgb"].shape[:2]
    n = f["embeddings"].shape[0]
    scaled = f["T_world_camera"].copy()
    scaled[:3, :3] *= 2.0
    bad_last = f["T_world_camera"].copy()
    bad_last[3, 0] = 1.0
    nan_t = f["T_world_camera"].copy()
    nan_t[0, 3] = np.nan
    bad_k = f["K"].copy()
    bad_k[0, 0] = -1.0
    nan_k = f["K"].copy()
    nan_k[1, 2] = np.nan
    stray = f["regions"].copy()
    stray[0, 0] = n + 5
    nan_e = f["embeddings"].copy()
    nan_e[0, 0] = np.nan
    return [
        ("rgb of floats", with_(f, rgb=f["rgb"].astype(np.float32)), ValueError, "rgb must be a uint8 array"),
        ("rgb without channels", with_(f, rgb=f["rgb"][:, :, 0].copy()), ValueError, "rgb must have shape [H, W, 3]"),
        ("rgba", with_(f, rgb=np.zeros((h, w, 4), np.uint8)), ValueError, "rgb must have shape [H, W, 3]"),
        ("rgb as a list", with_(f, rgb=f["rgb"].tolist()), ValueError, "rgb must be a uint8 array"),
        ("depth of another size", with_(f, depth=f["depth"][:-1]), ValueError, "depth must have the colour image's shape"),
        ("depth of int32", with_(f, depth=f["depth"].astype(np.int32)), ValueError, "uint16 (millimetres) or float32 (metres)"),
        ("K of 2×3", with_(f, K=f["K"][:2]), ValueError, "K must be 3×3"),
        ("K with a negative focal length", with_(f, K=bad_k), ValueError, "pinhole camera"),
        ("K with NaN", with_(f, K=nan_k), ValueError, "not finite"),
        ("a scaled pose", with_(f, T_world_camera=scaled), ValueError, "not a rigid transform"),
        ("a pose with a bad last row", with_(f, T_world_camera=bad_last), ValueError, "last row must be [0, 0, 0, 1]"),
        ("a pose with NaN", with_(f, T_world_camera=nan_t), ValueError, "not finite"),
        ("a pose of 3×4", with_(f, T_world_camera=f["T_world_camera"][:3]), ValueError, "T_world_camera must be 4×4"),
        ("regions without embeddings", with_(f, embeddings=None), ValueError, "come together"),
        ("embeddings of ints", with_(f, embeddings=f["embeddings"].astype(np.int32)), ValueError, "float16 or float32"),
        ("regions of another size", with_(f, regions=f["regions"][:, :-1].copy()), ValueError, "regions must have shape"),
        ("a region with no embedding", with_(f, regions=stray), ValueError, f"region {n + 5} in the mask"),
        ("embeddings with NaN", with_(f, embeddings=nan_e), ValueError, "not finite"),
        ("embeddings of one dimension", with_(f, embeddings=f["embeddings"][0].copy()), ValueError, "shape [N, D]"),
    ]


def test_misuse_raises_clear_errors(scene):
    f = base_frame(scene)
    mapper = latentam.Mapper()
    cases = misuse_cases(f)
    assert len(cases) >= 15
    for name, frame, kind, words in cases:
        with pytest.raises(kind, match=None) as caught:
            mapper.submit(**frame)
        assert words in str(caught.value), f"{name}: {caught.value}"
    # Nothing reached the mapper; it maps on.
    assert mapper.status()["submitted"] == 0
    text = np.ones(64, np.float32)
    with pytest.raises(latentam.NoEmbeddingsError):
        mapper.query(text)
    mapper.submit(**f)
    while mapper.status()["keyframes"] < 1:
        time.sleep(0.02)
    with pytest.raises(latentam.EmbeddingMismatchError, match="32-d embeddings"):
        mapper.query(np.ones(32, np.float32))
    with pytest.raises(ValueError, match="shape"):
        mapper.query(np.ones((2, 2, 2), np.float32))
    with pytest.raises(ValueError, match="`sofa` is not in the vocabulary"):
        mapper.query_names(["a", "b"], np.ones((2, 64), np.float32), "sofa")
    with pytest.raises(ValueError, match="2 names for 3 vectors"):
        mapper.query_names(["a", "b"], np.ones((3, 64), np.float32), "a")
    with pytest.raises(ValueError, match="1 to 16384 pixels"):
        mapper.render(f["T_world_camera"], f["K"], 0, 10)
    # Embeddings of another model: refused by the map, counted, mapping goes on.
    later = with_(f, stamp_ns=f["stamp_ns"] + 10**9, model="another-model")
    mapper.submit(**later)
    while mapper.status()["integrated"] < 2:
        time.sleep(0.02)
    status = mapper.status()
    assert status["dropped"]["rejected"] == 1
    assert "another-model" in status["last_error"]
    mapper.finish()
    with pytest.raises(latentam.StoppedError):
        mapper.submit(**f)
    with pytest.raises(latentam.InputError):
        latentam.LogFrames("/nonexistent/log.mcap")
    with pytest.raises(ValueError):
        latentam.Mapper(config="voxel_size = -1")


def test_errors_say_what_to_fix_by_their_class(scene, tmp_path):
    """A program tells a bad argument, a bad setting and a damaged file
    apart by the exception's class, not by its words."""
    # A setting out of range: ConfigError, still a ValueError.
    with pytest.raises(latentam.ConfigError, match="voxel_size") as caught:
        latentam.Mapper(config="voxel_size = -1")
    assert isinstance(caught.value, ValueError)
    assert not isinstance(caught.value, latentam.BadInputError)
    # An array that does not fit: BadInputError, still a ValueError.
    f = base_frame(scene)
    with pytest.raises(latentam.BadInputError, match="rgb"):
        latentam.Mapper().submit(**with_(f, rgb=f["rgb"].astype(np.float32)))
    # A saved map with one byte changed: DamagedFileError, an InputError.
    run("map", str(scene), "--out", str(tmp_path / "run"), "--frames", "8")
    state = tmp_path / "run" / "state.latentam"
    data = bytearray(state.read_bytes())
    data[-5] ^= 0x40
    state.write_bytes(bytes(data))
    with pytest.raises(latentam.DamagedFileError, match="is damaged") as caught:
        latentam.Mapper.load(tmp_path / "run")
    assert isinstance(caught.value, latentam.InputError)
    assert str(state) in str(caught.value)
    # The budget kind sits under GPU memory errors.
    assert issubclass(latentam.BudgetError, latentam.GpuMemoryError)


def test_a_host_budget_set_from_python_spills_the_map_where_asked(scene, tmp_path):
    """host_budget and spill_dir as a robot's Python code sets them: the
    map spills to the folder named (its scratch file unlinked at once, so
    the folder stays empty), saves and loads like the map kept in memory,
    and a spill folder that cannot be made stops mapping with an error
    naming it."""
    frames = frames_of(scene)
    spill = tmp_path / "spill"
    spilled = latentam.Mapper(config=f'host_budget = 1\nspill_dir = "{spill}"', **NO_DROPS)
    in_memory = latentam.Mapper(**NO_DROPS)
    for frame in frames:
        spilled.submit(**frame)
        in_memory.submit(**frame)
    spilled.finish()
    in_memory.finish()
    assert spill.is_dir() and list(spill.iterdir()) == []
    spilled.save(tmp_path / "spilled")
    ours = latentam.Mapper.load(tmp_path / "spilled").snapshot()
    theirs = in_memory.snapshot()
    assert ours.keyframes == theirs.keyframes == 6
    # Float rounding differs between runs (atomic adds); the map does not.
    assert abs(len(ours) - len(theirs)) <= len(theirs) // 200, (len(ours), len(theirs))

    blocked = tmp_path / "a-file"
    blocked.write_text("not a folder")
    mapper = latentam.Mapper(config=f'host_budget = 1\nspill_dir = "{blocked}"', **NO_DROPS)
    with pytest.raises(latentam.Error) as raised:
        for frame in frames:
            mapper.submit(**frame)
        mapper.finish()
    assert str(blocked) in str(raised.value), raised.value
