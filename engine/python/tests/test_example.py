"""The folder example (numpy + Pillow) on real 7-Scenes frames gives the
map `latentam convert 7scenes --no-registration` then `latentam map` give:
the same keyframes, Gaussians within 0.5 %, held-out PSNR within 0.1 dB."""

import json
import pathlib
import subprocess
import sys

import latentam
from conftest import REPO, run

DATA = REPO.parent / "shared" / "data" / "7scenes-redkitchen"
FRAMES = "24"


def test_the_folder_example_maps_as_convert_and_map_do(tmp_path):
    assert DATA.is_dir(), f"{DATA} is missing (the shared test data sits beside the repository)"
    example = REPO / "engine" / "python" / "examples" / "map_folder.py"
    out = subprocess.run(
        [sys.executable, str(example), str(DATA), str(tmp_path / "python"), "--frames", FRAMES],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    assert f"{FRAMES} frames in" in out.stdout, out.stdout

    log = tmp_path / "kitchen.mcap"
    run("convert", "7scenes", str(DATA), "--no-registration", "--max-frames", FRAMES, "-o", str(log))
    run("map", str(log), "--out", str(tmp_path / "cli"))

    ours = latentam.Mapper.load(tmp_path / "python").snapshot()
    theirs = latentam.Mapper.load(tmp_path / "cli").snapshot()
    assert ours.keyframes == theirs.keyframes == 6
    assert abs(len(ours) - len(theirs)) <= len(theirs) // 200, (len(ours), len(theirs))

    def psnr(run_dir: pathlib.Path) -> float:
        report = tmp_path / f"{run_dir.name}.json"
        run("eval", str(run_dir), str(log), "--every", "8", "--offset", "2", "--json", str(report))
        return json.loads(report.read_text())["mean"]["psnr"]

    a, b = psnr(tmp_path / "python"), psnr(tmp_path / "cli")
    assert abs(a - b) < 0.1, (a, b)
