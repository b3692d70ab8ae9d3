"""The `canopy` command as a user runs it: a real process, its output and exit codes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from canopy_core.cloud_io import read_cloud
from tests.core.edits import take_away_blue_ball

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
    written = read_cloud(cloud)
    points = written.points_m
    assert cloud.read_bytes().startswith(b"ply\nformat binary_little_endian")
    assert points.shape[0] > 1000 and written.colors_rgb is not None
    assert points[:, 2].max() == pytest.approx(document["height_m"], abs=0.1)


REASON_CODES = {"radius", "points", "residual", "coverage", "colour", "floating", "taken", "inconsistent"}


@pytest.fixture(scope="module")
def balls_run(capture: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    """`canopy balls --json --preview` on the capture, once: the document and the (new) preview folder."""
    preview = tmp_path_factory.mktemp("preview") / "not" / "yet"
    done = _run("balls", str(capture), "--json", "--preview", str(preview))
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout), preview


def test_balls_json_reports_every_view_and_colour(balls_run: tuple[dict, Path]) -> None:
    document, _ = balls_run
    assert "error" not in document
    views = document["views"]
    assert set(views) == {"views/1", "views/2"}
    rejected = []
    for fits in views.values():
        assert set(fits) == {"red", "yellow", "blue"}
        for fit in fits.values():
            assert len(fit["center_m"]) == 3 and np.isfinite(fit["center_m"]).all()
            assert fit["radius_m"] == pytest.approx(0.05, abs=0.01) and fit["points"] > 0
            assert fit["rms_m"] >= 0 and len(fit["rejected"]) <= 5
            rejected += fit["rejected"]
    assert rejected, "the simulated scene has spheres that are not balls (the post, apples in the crown)"
    for sphere in rejected:
        assert {"center_m", "radius_m", "points", "reason", "code"} <= set(sphere)
        assert sphere["code"] in REASON_CODES and sphere["reason"]


def _project_truth(capture: Path, view: str, color: str) -> tuple[np.ndarray, float]:
    """Where the simulator put a ball in a view's colour image: pixel centre and radius, full size."""
    truth = json.loads((capture / "ground_truth.json").read_text())
    camera = json.loads((capture / view / "camera.json").read_text())
    world = np.append(truth["balls"][color]["center_m"], 1.0)
    in_depth = np.linalg.inv(np.array(truth["views"][view]["camera_to_world"])) @ world
    in_color = np.array(camera["depth_to_color"]) @ in_depth
    intrinsics = camera["color_intrinsics"]
    x, y, z = in_color[:3]
    centre = np.array(
        [intrinsics["fx"] * x / z + intrinsics["cx"], intrinsics["fy"] * y / z + intrinsics["cy"]]
    )
    return centre, intrinsics["fx"] * truth["balls"][color]["diameter_m"] / 2 / z


def test_balls_preview_circles_each_ball_in_its_colour(capture: Path, balls_run: tuple[dict, Path]) -> None:
    from canopy_core.ball_preview import ball_rgb
    from canopy_core.config import BallConfig

    _, preview = balls_run
    assert sorted(p.name for p in preview.iterdir()) == ["views_1.png", "views_2.png"]
    for view in ("views/1", "views/2"):
        image = np.asarray(Image.open(preview / f"{view.replace('/', '_')}.png").convert("RGB"))
        color_image = Image.open(next((capture / view).glob("color.*")))
        assert image.shape[1] <= 960
        assert image.shape[1] / image.shape[0] == pytest.approx(
            color_image.width / color_image.height, rel=0.01
        )
        scale = image.shape[1] / color_image.width
        for color in ("red", "yellow", "blue"):
            centre, radius = _project_truth(capture, view, color)
            drawn = np.array(ball_rgb(color, BallConfig()))
            angles = np.linspace(0, 2 * np.pi, 24, endpoint=False)
            ring = [
                np.rint(centre * scale + (radius * scale + offset) * np.array([np.cos(a), np.sin(a)]))
                for a in angles
                for offset in (2, 3, 4)  # the outline, 3 px thick, lies just outside the ball
            ]
            hits = [np.abs(image[int(v), int(u)].astype(int) - drawn).max() <= 12 for u, v in ring]
            assert np.mean(hits) > 0.8, (view, color)  # 0.2 or less with the colour camera's offset ignored
            u, v = np.rint(centre * scale).astype(int)  # the ball itself stays in sight, undrawn
            assert np.abs(image[v, u].astype(int) - drawn).max() > 12, (view, color)


def test_balls_failing_selection_still_shows_every_view_and_exits_2(capture: Path, tmp_path: Path) -> None:
    import shutil

    broken = Path(shutil.copytree(capture, tmp_path / "broken"))
    take_away_blue_ball(broken, "views/2")
    done = _run("balls", str(broken), "--json", "--preview", str(tmp_path / "preview"))
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "views/2" in lines[0] and "blue" in lines[0]
    document = json.loads(done.stdout)
    assert document["error"]["view"] == "views/2" and document["error"]["color"] == "blue"
    views = document["views"]
    assert all("center_m" in views["views/1"][color] for color in ("red", "yellow", "blue"))
    assert all("center_m" in views["views/2"][color] for color in ("red", "yellow"))
    assert "center_m" not in views["views/2"]["blue"] and views["views/2"]["blue"]["problem"]
    assert sorted(p.name for p in (tmp_path / "preview").iterdir()) == ["views_1.png", "views_2.png"]

    text = _run("balls", str(broken))
    assert text.returncode == 2 and text.stderr.strip() == lines[0]
    shown = text.stdout.splitlines()
    assert shown[0].startswith("ball selection failed")
    for color in ("red", "yellow", "blue"):
        assert any(line.startswith(f"views/1 {color:<7} centre (") for line in shown)
    assert any(line.startswith("views/2 blue    no ball: ") for line in shown)


def test_balls_with_one_colour_chooses_in_each_view_alone(
    capture: Path, balls_run: tuple[dict, Path], tmp_path: Path
) -> None:
    import shutil

    single = Path(shutil.copytree(capture, tmp_path / "yellow"))
    manifest = json.loads((single / "capture.json").read_text())
    manifest["calibration_balls"]["colors"] = ["yellow"]
    (single / "capture.json").write_text(json.dumps(manifest))
    done = _run("balls", str(single), "--json", "--all")
    assert done.returncode == 0, done.stderr
    for view, fits in json.loads(done.stdout)["views"].items():
        assert list(fits) == ["yellow"]
        found, with_three = fits["yellow"], balls_run[0]["views"][view]["yellow"]
        assert found["center_m"] == pytest.approx(with_three["center_m"], abs=0.005)
        assert all(sphere["code"] in {*REASON_CODES, "weaker"} for sphere in found["rejected"])


def test_balls_preview_into_a_file_fails_naming_the_option(capture: Path, tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    done = _run("balls", str(capture), "--preview", str(blocker / "preview"))
    assert done.returncode == 2 and done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "--preview" in lines[0]


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


def test_version_prints_the_installed_version() -> None:
    from importlib.metadata import version

    done = _run("--version")
    assert done.returncode == 0
    assert done.stdout.strip() == f"canopy {version('canopy')}"


_PARTS_LOADED = """
import sys
from canopy_core.cli import command_line
command_line(sys.argv[1:])
print(sorted(name for name in sys.modules if name.startswith("service")))
"""


def test_a_core_command_starts_without_looking_up_the_other_parts_commands() -> None:
    def parts_loaded(*arguments: str) -> str:
        done = subprocess.run(
            [sys.executable, "-c", _PARTS_LOADED, *arguments], capture_output=True, text=True, timeout=60
        )
        assert done.returncode == 0, done.stderr
        return done.stdout.strip()

    assert parts_loaded("measure", "somewhere") == "[]"
    assert "service.cli" in parts_loaded("serve")
    assert "service.client.cli" in parts_loaded("--help")


@pytest.mark.parametrize(
    ("command", "argument"), [("measure", "CAPTURE"), ("upload", "ROOT"), ("simulate", "OUT")]
)
def test_help_names_arguments_in_capitals_and_flags_without_a_type(command: str, argument: str) -> None:
    done = _run(command, "--help")
    assert done.returncode == 0
    assert f"Usage: canopy {command} [OPTIONS] {{{argument}}}" in done.stdout
    assert "<bool>" not in done.stdout


def test_simulate_refuses_an_unknown_sensor_naming_the_known_ones(tmp_path: Path) -> None:
    done = _run("simulate", str(tmp_path / "out"), "--sensor", "kinect-v3")
    assert done.returncode == 2
    assert "unknown sensor 'kinect-v3'" in done.stderr and "azure-kinect-nfov-binned" in done.stderr
    assert not (tmp_path / "out").exists()


def test_set_changes_a_setting_for_that_measurement(capture: Path) -> None:
    done = _run(
        "measure", str(capture), "--json", "--set", "metrics.max_thin_top_m=0.4", "--set", "roi.radius_m=1.6"
    )
    assert done.returncode == 0, done.stderr
    config = json.loads(done.stdout)["config"]
    assert config["metrics"]["max_thin_top_m"] == 0.4 and config["roi"]["radius_m"] == 1.6
    # It takes effect: a region narrower than the crown is refused at its wall, naming the setting.
    narrow = _run("measure", str(capture), "--set", "roi.radius_m=0.3")
    assert narrow.returncode == 2 and "region of interest's wall" in narrow.stderr
    assert "roi.radius_m" in narrow.stderr


@pytest.mark.parametrize(
    ("assignments", "named"),
    [
        (
            ["metrics.max_thin_top=0.4"],
            "metrics.max_thin_top: unknown field; did you mean 'max_thin_top_m'? docs/configuration.md",
        ),
        (['roi.radius_m="wide"'], "roi.radius_m: Input should be a valid number"),
        (["roi.max_height_m=Infinity"], "roi.max_height_m: Input should be a finite number"),
        (["roi.radius_m=wide"], "--set 'roi.radius_m=wide': 'wide' is not a JSON value"),
        (["roi.radius_m="], "--set 'roi.radius_m=': '' is not a JSON value"),
        (["metrics"], "--set 'metrics': expected KEY=VALUE"),
        (["metrics..edge_px=1"], "--set 'metrics..edge_px=1': expected KEY=VALUE"),
        (["balls.colors.x=1"], "balls.colors: Input should be a valid list"),
    ],
)
def test_set_refuses_what_is_not_a_setting_in_one_line_naming_it(
    capture: Path, assignments: list[str], named: str
) -> None:
    done = _run(
        "measure", str(capture), *(arg for assignment in assignments for arg in ("--set", assignment))
    )
    assert done.returncode == 2 and done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and named in lines[0]


def test_set_values_are_json_and_combine_as_a_job_config_does() -> None:
    from canopy_core.cli import settings_overrides

    assert settings_overrides(None) is None
    assert settings_overrides(
        [
            "metrics.max_thin_top_m=0.4",
            " icp . enabled = false",
            'balls.colors=["red", "blue"]',
            "metrics.edge_px=1",
            "roi.radius_m=1.0",
            "roi.radius_m=2.0",
        ]
    ) == {
        "metrics": {"max_thin_top_m": 0.4, "edge_px": 1},
        "icp": {"enabled": False},
        "balls": {"colors": ["red", "blue"]},
        "roi": {"radius_m": 2.0},
    }
    # A whole section given as an object merges with settings given one by one, as in a job's config.
    assert settings_overrides(["metrics.edge_px=1", 'metrics={"crown_link_m": 0.2}']) == {
        "metrics": {"edge_px": 1, "crown_link_m": 0.2}
    }


def test_balls_take_set_settings_too(capture: Path) -> None:
    done = _run("balls", str(capture), "--json", "--set", 'balls.colors=["yellow"]')
    assert done.returncode == 0, done.stderr
    views = json.loads(done.stdout)["views"]
    assert views and all(list(fits) == ["yellow"] for fits in views.values())


def test_settings_prints_the_settings_reference() -> None:
    from canopy_core.settings_reference import settings_reference

    done = _run("settings")
    assert done.returncode == 0, done.stderr
    assert done.stdout == settings_reference()
