"""Loading a capture folder: a valid one loads; every defect is one CaptureError naming view, file, field."""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from canopy_core.capture import folder_reader, load_capture, parse_camera, read_capture, stored_manifest
from canopy_core.errors import CaptureError
from canopy_core.images import decode_color

from .conftest import CAMERA


def _edit_json(path: Path, change) -> None:
    document = json.loads(path.read_text())
    change(document)
    path.write_text(json.dumps(document))


def _error(capture_dir: Path) -> CaptureError:
    with pytest.raises(CaptureError) as info:
        load_capture(capture_dir)
    return info.value


def test_valid_registered_capture_loads_with_depth_in_metres(capture_dir: Path) -> None:
    capture = load_capture(capture_dir)
    assert [view.name for view in capture.views] == ["views/1", "views/2"]
    view = capture.views[0]
    assert view.depth_raw.dtype == np.uint16 and view.depth_raw.shape == (48, 64)
    assert view.color_rgb.shape == (48, 64, 3) and view.color_rgb.dtype == np.uint8
    assert view.camera.registered
    assert float(view.depth_m[0, 0]) == pytest.approx(2.0)
    assert capture.manifest.calibration_balls.diameter_m == 0.10


def test_native_pair_with_larger_colour_image_and_extrinsics_loads(capture_dir: Path) -> None:
    camera = {
        **CAMERA,
        "color_intrinsics": {"width": 128, "height": 96, "fx": 100.0, "fy": 100.0, "cx": 64.0, "cy": 48.0},
        "depth_to_color": [[1, 0, 0, 0.052], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
    }
    (capture_dir / "views/1/camera.json").write_text(json.dumps(camera))
    Image.fromarray(np.zeros((96, 128, 3), dtype=np.uint8)).save(capture_dir / "views/1/color.png")
    view = load_capture(capture_dir).views[0]
    assert not view.camera.registered
    assert view.camera.depth_to_color[0, 3] == pytest.approx(0.052)


def test_jpeg_colour_is_accepted(capture_dir: Path) -> None:
    (capture_dir / "views/2/color.png").unlink()
    Image.fromarray(np.full((48, 64, 3), 90, dtype=np.uint8)).save(capture_dir / "views/2/color.jpg")
    assert load_capture(capture_dir).views[1].color_rgb.shape == (48, 64, 3)


def test_missing_depth_file_names_view_and_file(capture_dir: Path) -> None:
    (capture_dir / "views/2/depth.png").unlink()
    error = _error(capture_dir)
    assert (error.view, error.file) == ("views/2", "views/2/depth.png")
    assert "missing" in error.message


def test_missing_colour_file_names_view(capture_dir: Path) -> None:
    (capture_dir / "views/1/color.png").unlink()
    error = _error(capture_dir)
    assert error.view == "views/1" and "colour image is missing" in error.message


def test_missing_capture_json_is_named(capture_dir: Path) -> None:
    (capture_dir / "capture.json").unlink()
    assert _error(capture_dir).file == "capture.json"


def test_eight_bit_depth_is_refused_as_not_16_bit(capture_dir: Path) -> None:
    Image.fromarray(np.full((48, 64), 200, dtype=np.uint8)).save(capture_dir / "views/1/depth.png")
    error = _error(capture_dir)
    assert error.file == "views/1/depth.png" and "16-bit single-channel" in error.message


def test_three_channel_depth_is_refused(capture_dir: Path) -> None:
    Image.fromarray(np.zeros((48, 64, 3), dtype=np.uint8)).save(capture_dir / "views/1/depth.png")
    assert "16-bit single-channel" in _error(capture_dir).message


def test_depth_size_disagreeing_with_camera_json_is_refused(capture_dir: Path) -> None:
    Image.fromarray(np.full((40, 64), 1000, dtype=np.uint16)).save(capture_dir / "views/2/depth.png")
    error = _error(capture_dir)
    assert error.file == "views/2/depth.png" and "64x40" in error.message and "64x48" in error.message


def test_colour_size_disagreeing_with_camera_json_is_refused(capture_dir: Path) -> None:
    Image.fromarray(np.zeros((48, 60, 3), dtype=np.uint8)).save(capture_dir / "views/1/color.png")
    error = _error(capture_dir)
    assert error.file == "views/1/color.png" and "60x48" in error.message


def test_depth_without_any_valid_pixel_is_refused(capture_dir: Path) -> None:
    Image.fromarray(np.zeros((48, 64), dtype=np.uint16)).save(capture_dir / "views/1/depth.png")
    assert "no valid pixel" in _error(capture_dir).message


def test_truncated_png_is_refused_as_corrupt(capture_dir: Path) -> None:
    path = capture_dir / "views/1/depth.png"
    path.write_bytes(path.read_bytes()[:60])
    error = _error(capture_dir)
    assert error.file == "views/1/depth.png"
    assert "truncated" in error.message or "not a readable" in error.message


def test_garbage_colour_file_is_refused(capture_dir: Path) -> None:
    (capture_dir / "views/2/color.png").write_bytes(b"this is not an image")
    error = _error(capture_dir)
    assert error.file == "views/2/color.png" and "not a readable" in error.message


@pytest.mark.parametrize(
    ("field", "value", "expected"),
    [
        ("fx", 0.0, "greater than 0"),
        ("fy", -365.0, "greater than 0"),
        ("cx", float("nan"), "finite number"),
        ("fx", float("inf"), "finite number"),
    ],
)
def test_bad_intrinsics_name_the_field(capture_dir: Path, field: str, value: float, expected: str) -> None:
    path = capture_dir / "views/2/camera.json"
    document = json.loads(path.read_text())
    document["depth_intrinsics"][field] = value
    path.write_text(json.dumps(document))  # json writes NaN/Infinity, as a careless exporter would
    error = _error(capture_dir)
    assert error.file == "views/2/camera.json" and error.view == "views/2"
    assert expected in error.message
    assert error.field == f"depth_intrinsics.{field}"


def test_missing_intrinsics_field_is_named(capture_dir: Path) -> None:
    _edit_json(capture_dir / "views/1/camera.json", lambda d: d["depth_intrinsics"].pop("fy"))
    error = _error(capture_dir)
    assert error.field == "depth_intrinsics.fy" and "required" in error.message.lower()


def test_colour_intrinsics_without_extrinsics_is_refused(capture_dir: Path) -> None:
    _edit_json(
        capture_dir / "views/1/camera.json",
        lambda d: d.update(color_intrinsics=dict(d["depth_intrinsics"])),
    )
    assert "given together" in _error(capture_dir).message


def test_depth_to_color_that_is_not_rigid_is_refused(capture_dir: Path) -> None:
    def change(document: dict) -> None:
        document["color_intrinsics"] = dict(document["depth_intrinsics"])
        document["depth_to_color"] = [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]

    _edit_json(capture_dir / "views/1/camera.json", change)
    assert "not a rotation" in _error(capture_dir).message


@pytest.mark.parametrize("bad", ["../outside", "/etc/views", "views/../x", "views/a/b", "other/1"])
def test_view_path_outside_the_capture_is_refused(capture_dir: Path, bad: str) -> None:
    _edit_json(capture_dir / "capture.json", lambda d: d.update(views=[bad]))
    error = _error(capture_dir)
    assert error.file == "capture.json" and error.field == "views"


def test_unknown_format_version_is_refused(capture_dir: Path) -> None:
    _edit_json(capture_dir / "capture.json", lambda d: d.update(format="canopy-capture/9"))
    error = _error(capture_dir)
    assert error.field == "format" and "canopy-capture/1" in error.message


def test_colour_without_default_range_needs_an_hsv_override(capture_dir: Path) -> None:
    _edit_json(capture_dir / "capture.json", lambda d: d["calibration_balls"].update(colors=["red", "teal"]))
    assert "teal" in _error(capture_dir).message


def test_oversized_image_is_refused_from_its_header(capture_dir: Path) -> None:
    with pytest.raises(CaptureError, match="exceeds the limit"):
        load_capture(capture_dir, max_pixels=1000)


@pytest.mark.parametrize("spelling", ["views/1/", "views//1", "views/./1"])
def test_view_path_must_be_spelled_canonically(capture_dir: Path, spelling: str) -> None:
    _edit_json(capture_dir / "capture.json", lambda d: d.update(views=["views/1", spelling]))
    assert _error(capture_dir).field == "views"


def test_hue_beyond_opencv_scale_is_refused(capture_dir: Path) -> None:
    _edit_json(
        capture_dir / "capture.json",
        lambda d: d["calibration_balls"].update(hsv={"red": [[250, 0, 0], [255, 255, 255]]}),
    )
    error = _error(capture_dir)
    assert "0-180" in error.message and error.field.startswith("calibration_balls.hsv")


def test_what_capture_software_records_besides_is_kept_under_extras(capture_dir: Path) -> None:
    _edit_json(
        capture_dir / "views/1/camera.json",
        lambda d: d.update(extras={"serial": "003154", "distortion": [0]}),
    )
    _edit_json(capture_dir / "capture.json", lambda d: d.update(extras={"operator": "Ana"}))
    capture = load_capture(capture_dir)
    assert capture.views[0].camera.depth.fx == 50.0 and capture.manifest.extras == {"operator": "Ana"}


@pytest.mark.parametrize(
    ("file", "edit", "field", "meant"),
    [
        (
            "views/1/camera.json",
            lambda d: d.update(depth_scael=d.pop("depth_scale")),
            "depth_scael",
            "depth_scale",
        ),
        (
            "views/1/camera.json",
            lambda d: d["depth_intrinsics"].update(fxx=d["depth_intrinsics"].pop("fx")),
            "depth_intrinsics.fxx",
            "fx",
        ),
        ("capture.json", lambda d: d.update(tre=d.pop("tree")), "tre", "tree"),
        (
            "capture.json",
            lambda d: d.update(calibration_balls={"diamter_m": 0.1}),
            "calibration_balls.diamter_m",
            "diameter_m",
        ),
    ],
)
def test_a_misspelt_key_is_refused_naming_the_key_it_was_meant_to_be(
    capture_dir: Path, file: str, edit: Callable[[dict], None], field: str, meant: str
) -> None:
    """Read as absent, a misspelt depth_scale took the default and gave wrong metres without a word."""
    _edit_json(capture_dir / file, edit)
    error = _error(capture_dir)
    assert error.file == file and error.field == field
    assert f"{field}: unknown field; did you mean '{meant}'?" in error.message
    assert "extras" in (error.hint or "")


def test_every_problem_of_a_file_is_listed(capture_dir: Path) -> None:
    def edit(camera: dict) -> None:
        camera["depth_intrinsics"]["fxx"] = camera["depth_intrinsics"].pop("fx")
        camera["depth_intrinsics"]["cy"] = "middle"
        camera["serial"] = "003154"

    _edit_json(capture_dir / "views/1/camera.json", edit)
    message = _error(capture_dir).message
    for problem in (
        "depth_intrinsics.fxx: unknown field",
        "serial: unknown field",
        "depth_intrinsics.fx: Field required",
        "depth_intrinsics.cy: Input should be a valid number",
    ):
        assert problem in message, problem


def test_a_camera_without_its_depth_scale_is_refused(capture_dir: Path) -> None:
    """Depth units differ between sensors and drivers (1000 or 4000 a metre, or 1): no default is safe."""
    _edit_json(capture_dir / "views/1/camera.json", lambda d: d.pop("depth_scale"))
    error = _error(capture_dir)
    assert error.field == "depth_scale" and "required" in error.message


def test_decompression_bomb_is_refused_before_decoding() -> None:
    """A PNG of a few kilobytes that would decode to 147 MB of pixels."""
    import io

    from canopy_core.images import decode_color

    buffer = io.BytesIO()
    Image.new("RGB", (7000, 7000)).save(buffer, format="PNG")
    assert len(buffer.getvalue()) < 500_000
    with pytest.raises(CaptureError, match="7000x7000 pixels exceeds the limit"):
        decode_color(buffer.getvalue(), file="views/1/color.png")


def test_a_capture_accepted_before_the_format_became_strict_is_still_read_as_it_was(
    capture_dir: Path,
) -> None:
    """Until 2026-11-24 capture.json kept unknown keys and camera.json ignored them and took a missing
    depth_scale as 1000: what the service stored then (and queued jobs) is read as it was accepted, while
    the same files are refused as new uploads."""
    manifest = json.loads((capture_dir / "capture.json").read_text())
    _edit_json(
        capture_dir / "views/1/camera.json", lambda d: (d.pop("depth_scale"), d.update(serial="003154"))
    )

    capture = read_capture(
        stored_manifest({**manifest, "operator": "Ana"}), folder_reader(capture_dir), stored=True
    )

    assert capture.manifest.extras == {"operator": "Ana"}
    assert capture.views[0].camera.depth_scale == 1000.0
    with pytest.raises(CaptureError, match="serial: unknown field"):
        load_capture(capture_dir)


# --- hostile and mistaken files: each refused naming the file and what is wrong, never a crash -------------


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            lambda d: d["depth_intrinsics"].update(cx=1e9),
            "principal point (1e+09, 24) lies outside the 64x48",
        ),
        (lambda d: d["depth_intrinsics"].update(cy=-3.0), "principal point (32, -3) lies outside"),
        (lambda d: d["depth_intrinsics"].update(fx=3.6, fy=3.6), "field of view of 167.2 degrees"),
        (lambda d: d["depth_intrinsics"].update(fx=5000.0, fy=5000.0), "field of view of 0.7 degrees"),
        (lambda d: d["depth_intrinsics"].update(fy=100.0), "differ too much"),
    ],
)
def test_implausible_intrinsics_are_refused_naming_the_camera_file(
    capture_dir: Path, change: Callable[[dict], None], message: str
) -> None:
    """A principal point off the image or a focal length in millimetres would scale every metre measured;
    with cx 1e9 the job used to fail later with a misleading 'no red point in the view'."""
    _edit_json(capture_dir / "views/1/camera.json", change)
    error = _error(capture_dir)
    assert error.file == "views/1/camera.json" and error.field == "depth_intrinsics"
    assert message in error.message


def test_a_camera_file_in_utf16_is_refused_as_not_utf8(capture_dir: Path) -> None:
    path = capture_dir / "views/2/camera.json"
    path.write_bytes(path.read_text().encode("utf-16"))
    error = _error(capture_dir)
    assert error.file == "views/2/camera.json"
    assert "is not UTF-8 text" in error.message


def test_json_nested_thousands_deep_is_refused_not_a_crash(capture_dir: Path) -> None:
    (capture_dir / "capture.json").write_text("[" * 100_000 + "]" * 100_000)
    error = _error(capture_dir)
    assert error.file == "capture.json"
    assert "nested too deeply" in error.message


@pytest.mark.parametrize("name", ["T\x0007", "T07\n", "\tT07"])
def test_a_name_with_a_control_character_is_refused(capture_dir: Path, name: str) -> None:
    _edit_json(capture_dir / "capture.json", lambda d: d.update(tree=name))
    error = _error(capture_dir)
    assert error.file == "capture.json" and error.field == "tree"
    assert "control character" in error.message


def test_png_bytes_under_a_jpeg_name_are_refused_naming_the_file(capture_dir: Path) -> None:
    (capture_dir / "views/1/color.png").rename(capture_dir / "views/1/color.jpg")
    error = _error(capture_dir)
    assert error.file == "views/1/color.jpg"
    assert "holds a PNG image under a .jpg name" in error.message


def test_a_json_file_saved_with_a_byte_order_mark_is_read(capture_dir: Path) -> None:
    """Windows Notepad saves UTF-8 with a byte-order mark: still UTF-8."""
    path = capture_dir / "views/1/camera.json"
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    assert load_capture(capture_dir).views[0].camera.depth_scale == 1000.0


def test_files_accepted_before_the_newer_rules_are_still_read_as_accepted() -> None:
    """Nothing acknowledged is refused later: a stored camera.json in UTF-16 with a principal point off
    the image, a stored capture.json whose tree name holds a tab, PNG bytes stored as color.jpg."""
    camera = {
        "depth_intrinsics": {"width": 64, "height": 48, "fx": 50.0, "fy": 50.0, "cx": 1e9, "cy": 24.0},
        "depth_scale": 1000.0,
    }
    stored_camera = json.dumps(camera).encode("utf-16")
    with pytest.raises(CaptureError):
        parse_camera(stored_camera, file="views/1/camera.json")
    assert parse_camera(stored_camera, file="views/1/camera.json", stored=True).depth.cx == 1e9

    manifest = {
        "format": "canopy-capture/1",
        "orchard": "North block",
        "row": "R12",
        "tree": "T\t07",
        "captured_at": "2026-11-20T08:31:00Z",
        "views": ["views/1"],
    }
    assert stored_manifest(manifest).tree == "T\t07"

    png = io.BytesIO()
    Image.fromarray(np.full((48, 64, 3), 128, dtype=np.uint8)).save(png, format="PNG")
    with pytest.raises(CaptureError):
        decode_color(png.getvalue(), file="views/1/color.jpg")
    assert decode_color(png.getvalue(), file="views/1/color.jpg", stored=True).shape == (48, 64, 3)
