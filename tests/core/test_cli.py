"""The `canopy` command as a user runs it: a real process, its output and exit codes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from canopy_core.cloud_io import read_ply

CANOPY = str(Path(sys.executable).with_name("canopy"))


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([CANOPY, *args], capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sim")
    done = _run("simulate", str(out), "--seed", "5", "--count", "1")
    assert done.returncode == 0, done.stderr
    return Path(done.stdout.split()[0])


def test_simulate_writes_captures_with_ground_truth(capture: Path) -> None:
    assert (capture / "capture.json").is_file() and (capture / "ground_truth.json").is_file()
    assert sorted(p.name for p in (capture / "views").iterdir()) == ["1", "2"]


def test_measure_json_prints_merged_metrics_modes_and_registration(capture: Path, tmp_path: Path) -> None:
    cloud = tmp_path / "tree.ply"
    done = _run("measure", str(capture), "--json", "--cloud", str(cloud))
    assert done.returncode == 0, done.stderr
    document = json.loads(done.stdout)
    for key in ("height_m", "width_m", "thickness_m"):
        assert document[key] > 0
        assert set(document["modes"]) == {"views/1", "views/2", "merged"}
        assert document["modes"]["merged"][key] == document[key]
    assert "views/2" in document["registration"]["views"]
    points, colors = read_ply(cloud)
    assert cloud.read_bytes().startswith(b"ply\nformat binary_little_endian")
    assert points.shape[0] > 1000 and colors is not None
    assert points[:, 2].max() == pytest.approx(document["height_m"], abs=0.1)


def test_balls_json_reports_every_view_and_colour(capture: Path) -> None:
    done = _run("balls", str(capture), "--json")
    assert done.returncode == 0, done.stderr
    views = json.loads(done.stdout)["views"]
    assert set(views) == {"views/1", "views/2"}
    for fits in views.values():
        assert set(fits) == {"red", "yellow", "blue"}
        for fit in fits.values():
            assert len(fit["center_m"]) == 3 and np.isfinite(fit["center_m"]).all()
            assert fit["radius_m"] == pytest.approx(0.05, abs=0.01) and fit["points"] > 0


def test_invalid_capture_exits_2_with_one_line_naming_the_file(capture: Path, tmp_path: Path) -> None:
    import shutil

    broken = Path(shutil.copytree(capture, tmp_path / "broken"))
    (broken / "views/2/depth.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    done = _run("measure", str(broken), "--json")
    assert done.returncode == 2 and done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "views/2/depth.png" in lines[0]


def test_cloud_into_a_missing_folder_fails_before_measuring(capture: Path, tmp_path: Path) -> None:
    done = _run("measure", str(capture), "--cloud", str(tmp_path / "no" / "such" / "tree.ply"))
    assert done.returncode == 2 and "does not exist" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
