"""The README's Python example, as written there, on the demo scene."""

import shutil
import subprocess
import sys

from conftest import REPO


def readme_python_example() -> str:
    text = (REPO / "README.md").read_text()
    blocks = text.split("```python\n")
    assert len(blocks) == 2, "the README should have one Python example"
    return blocks[1].split("```", 1)[0]


def test_the_readme_example_maps_queries_and_saves(scene, tmp_path):
    shutil.copy(scene, tmp_path / "scene.mcap")
    out = subprocess.run(
        [sys.executable, "-c", readme_python_example()],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    assert "Gaussians" in out.stdout and "keyframes" in out.stdout, out.stdout
    assert (tmp_path / "run" / "state.latentam").is_file()
