"""Shared fixtures: the latentam command (built by the Rust test run) and a
small generated scene."""

import os
import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[3]


def latentam_bin() -> str:
    """The `latentam` command: $LATENTAM_BIN, else the workspace's build."""
    path = os.environ.get("LATENTAM_BIN") or str(REPO / "target" / "debug" / "latentam")
    if not os.path.exists(path):
        pytest.fail(f"{path} is missing: build it with `cargo build -p latentam-cli` (tools/run test does)")
    return path


def run(*args: str) -> subprocess.CompletedProcess:
    out = subprocess.run([latentam_bin(), *args], capture_output=True, text=True)
    assert out.returncode == 0, f"latentam {' '.join(args)}:\n{out.stderr}"
    return out


@pytest.fixture(scope="session")
def scene(tmp_path_factory) -> pathlib.Path:
    """The demo scene, 24 frames of 160×120 with 64-d region embeddings."""
    path = tmp_path_factory.mktemp("scene") / "scene.mcap"
    run("gen-scene", "-o", str(path), "--frames", "24", "--dim", "64")
    return path
