"""The capture folder format, version 1: reading, validating and holding one tree's RGB-D views.

A capture is ``capture.json`` (the manifest), and per view ``color.png|jpg``, ``depth.png`` and
``camera.json``. Every defect raises :class:`CaptureError` naming the view, the file and the field. The
``parse_*`` functions take bytes so that the client, the service and ``canopy measure`` check with the
same rules.

Both JSON files are strict: a key the format does not know is refused, naming the nearest known one, since
a misspelt key read as absent would silently take a default (``depth_scael`` measured every depth with
the default scale). What capture software wants to record besides (a serial number, a lens distortion,
the operator) goes under ``extras``, which is kept and never read.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Collection
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from canopy_core.config import BallSet, RoiConfig
from canopy_core.errors import CaptureError
from canopy_core.images import DEFAULT_MAX_PIXELS, decode_color, decode_depth
from canopy_core.validation import validation_problems

__all__ = [
    "CAPTURE_FORMAT",
    "CameraModel",
    "Capture",
    "CaptureManifest",
    "FileReader",
    "Intrinsics",
    "View",
    "capture_time",
    "color_file_names",
    "expected_files",
    "folder_reader",
    "load_capture",
    "load_view",
    "parse_camera",
    "parse_manifest",
    "read_capture",
    "stored_manifest",
]

CAPTURE_FORMAT = "canopy-capture/1"
COLOR_NAMES = ("color.png", "color.jpg")


_CONTROL = re.compile(r"[\x00-\x1f\x7f]")
"""Names and view paths hold no control characters (a NUL, a newline): they become folder names, CSV
cells, URLs and log lines."""
_PRINTABLE = r"^[^\u0000-\u001f\u007f]+$"
"""The same rule as a JSON-schema pattern."""
_VIEW_PATH = r"^views/(?!\.\.?$)[^/\\\u0000-\u001f\u007f]+$"
"""A view path as a JSON-schema pattern: ``views/<name>``, the name neither ``.`` nor ``..``."""


_STORED = "stored"
"""Validation context key: the file was accepted earlier, perhaps before a rule was added; the rules added
since (control characters, plausible intrinsics, UTF-8) do not refuse what was acknowledged then."""


def _accepted_earlier(info: ValidationInfo) -> bool:
    return bool(info.context and info.context.get(_STORED))


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class CaptureManifest(_Strict):
    """The content of ``capture.json``."""

    # The validators below give these rules their own messages; json_schema_extra states them in the
    # JSON schema too (the OpenAPI document), so what the schema allows is what is accepted.
    format: str = Field(json_schema_extra={"const": CAPTURE_FORMAT})
    orchard: str = Field(min_length=1, max_length=200, json_schema_extra={"pattern": _PRINTABLE})
    row: str = Field(min_length=1, max_length=200, json_schema_extra={"pattern": _PRINTABLE})
    tree: str = Field(min_length=1, max_length=200, json_schema_extra={"pattern": _PRINTABLE})
    captured_at: str = Field(
        min_length=1,
        max_length=64,
        description="ISO 8601 with a time zone, e.g. 2026-11-20T08:31:00Z (the service needs the zone)",
        json_schema_extra={"format": "date-time"},
    )
    sensor: str = "unknown"
    calibration_balls: BallSet = Field(default_factory=BallSet)
    views: list[str] = Field(
        min_length=1,
        max_length=64,
        json_schema_extra={"uniqueItems": True, "items": {"type": "string", "pattern": _VIEW_PATH}},
    )
    roi: RoiConfig | None = None
    extras: dict[str, Any] = Field(default_factory=dict)

    @field_validator("format")
    @classmethod
    def _known_format(cls, value: str) -> str:
        if value != CAPTURE_FORMAT:
            raise ValueError(f"unsupported format {value!r}; expected {CAPTURE_FORMAT!r}")
        return value

    @field_validator("orchard", "row", "tree")
    @classmethod
    def _printable(cls, name: str, info: ValidationInfo) -> str:
        if _CONTROL.search(name) and not _accepted_earlier(info):
            raise ValueError(f"{name!r} holds a control character (a NUL, a tab, a newline)")
        return name

    @field_validator("views")
    @classmethod
    def _safe_view_paths(cls, views: list[str], info: ValidationInfo) -> list[str]:
        for view in views:
            path = PurePosixPath(view)
            if (
                (_CONTROL.search(view) and not _accepted_earlier(info))
                or str(path) != view
                or path.is_absolute()
                or "\\" in view
                or len(path.parts) != 2
                or path.parts[0] != "views"
                or path.parts[1] in {".", ".."}
            ):
                raise ValueError(f"view path {view!r} must be 'views/<name>' inside the capture")
        if len(set(views)) != len(views):
            raise ValueError("a view is listed twice")
        return views


_FIELD_OF_VIEW_DEG = (20.0, 150.0)
"""Every RGB-D camera a crew carries sees between these angles across its image's width: a focal length
outside them is a typo or another unit (millimetres for pixels), and would scale every metre."""
_PIXEL_ASPECT = (0.8, 1.25)
"""fy / fx: a camera's pixels are square to a per cent; a ratio off by more than a factor 1.25 is a typo."""


class _IntrinsicsModel(_Strict):
    width: int = Field(gt=0, le=20000)
    height: int = Field(gt=0, le=20000)
    fx: float = Field(gt=0.0, allow_inf_nan=False)
    fy: float = Field(gt=0.0, allow_inf_nan=False)
    cx: float = Field(allow_inf_nan=False)
    cy: float = Field(allow_inf_nan=False)

    @model_validator(mode="after")
    def _plausible(self, info: ValidationInfo) -> _IntrinsicsModel:
        if _accepted_earlier(info):
            return self
        if not (0.0 <= self.cx <= self.width and 0.0 <= self.cy <= self.height):
            raise ValueError(
                f"the principal point ({self.cx:g}, {self.cy:g}) lies outside the {self.width}x{self.height} "
                "image; cx and cy are pixels from its top-left corner"
            )
        field_of_view = float(np.degrees(2.0 * np.arctan(self.width / (2.0 * self.fx))))
        low, high = _FIELD_OF_VIEW_DEG
        if not low <= field_of_view <= high:
            raise ValueError(
                f"fx {self.fx:g} px gives a field of view of {field_of_view:.1f} degrees across the "
                f"{self.width}-pixel width, where a camera sees {low:.0f}-{high:.0f}; fx and fy are in pixels"
            )
        if not _PIXEL_ASPECT[0] <= self.fy / self.fx <= _PIXEL_ASPECT[1]:
            raise ValueError(
                f"fy {self.fy:g} and fx {self.fx:g} differ too much for a camera's square pixels"
            )
        return self


_FORMER_DEPTH_SCALE = 1000.0
"""The depth units per metre a camera.json without ``depth_scale`` was read with before it was required."""


class _CameraModel(_Strict):
    depth_intrinsics: _IntrinsicsModel
    depth_scale: float = Field(gt=0.0, allow_inf_nan=False)
    color_intrinsics: _IntrinsicsModel | None = None
    depth_to_color: list[list[float]] | None = None
    extras: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _extrinsics_complete(self) -> _CameraModel:
        if (self.color_intrinsics is None) != (self.depth_to_color is None):
            raise ValueError("color_intrinsics and depth_to_color must be given together, or neither")
        if self.depth_to_color is not None:
            _check_rigid(self.depth_to_color)
        return self


def _check_rigid(matrix: list[list[float]]) -> None:
    m = np.asarray(matrix, dtype=float)
    if m.shape != (4, 4):
        raise ValueError(f"depth_to_color must be a 4x4 matrix, got shape {m.shape}")
    if not np.isfinite(m).all():
        raise ValueError("depth_to_color has non-finite entries")
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
        raise ValueError("depth_to_color's last row must be [0, 0, 0, 1]")
    rotation = m[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-3) or np.linalg.det(rotation) < 0:
        raise ValueError("depth_to_color's upper-left 3x3 block is not a rotation")


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of one camera, in pixels; OpenCV axes (x right, y down, z forward)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels."""
        return (self.width, self.height)


@dataclass(frozen=True)
class CameraModel:
    """A view's depth camera and, for native pairs, its colour camera and the rigid map between them."""

    depth: Intrinsics
    depth_scale: float
    color: Intrinsics | None = None
    depth_to_color: np.ndarray | None = None

    @property
    def registered(self) -> bool:
        """True when the colour image is pixel-for-pixel registered to the depth image."""
        return self.color is None

    @property
    def color_size(self) -> tuple[int, int]:
        """``(width, height)`` the colour image must have."""
        return self.color.size if self.color is not None else self.depth.size


@dataclass(frozen=True)
class View:
    """One RGB-D pair: raw depth (uint16, ``depth_scale`` units per metre, 0 = none) and RGB colour."""

    name: str
    depth_raw: np.ndarray
    color_rgb: np.ndarray
    camera: CameraModel

    @property
    def depth_m(self) -> np.ndarray:
        """Depth along the optical axis in metres, float32, 0 where there is no reading."""
        return self.depth_raw.astype(np.float32) / np.float32(self.camera.depth_scale)


@dataclass(frozen=True)
class Capture:
    """A loaded, validated capture: its manifest and its views in manifest order."""

    root: Path | None
    manifest: CaptureManifest
    views: tuple[View, ...]


def _raise_validation(
    exc: ValidationError, model: type[BaseModel], *, file: str, view: str | None = None
) -> None:
    """Raise one :class:`CaptureError` listing every problem of ``exc``, naming the first one's field."""
    problems = validation_problems(exc, model)
    hint = (
        "keys the format does not know go under 'extras' (docs/capture-format.md)"
        if problems.unknown_key
        else None
    )
    raise CaptureError(problems.message, file=file, view=view, field=problems.field, hint=hint) from exc


def _load_json(data: bytes, *, file: str, view: str | None, stored: bool = False) -> Any:
    """The JSON value of a file that must be UTF-8 text, with or without a byte-order mark (``json.loads``
    would guess UTF-16 or UTF-32 from the bytes: one format, one encoding), nested no deeper than Python's
    parser reaches. A ``stored`` file, accepted before UTF-8 was required, is read as it was then."""
    if stored:
        text: str | bytes = data
    else:
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            raise CaptureError(
                f"is not UTF-8 text (byte {exc.start}); save it as UTF-8", file=file, view=view
            ) from exc
    try:
        # NaN and Infinity (which careless exporters write) parse as floats, so that validation names the
        # field that holds them.
        return json.loads(text)
    except ValueError as exc:
        raise CaptureError(f"not valid JSON ({exc})", file=file, view=view) from exc
    except RecursionError as exc:
        raise CaptureError("JSON nested too deeply to be a capture file", file=file, view=view) from exc


def parse_manifest(data: bytes, *, file: str = "capture.json") -> CaptureManifest:
    """Parse and validate the bytes of ``capture.json``."""
    raw = _load_json(data, file=file, view=None)
    if not isinstance(raw, dict):
        raise CaptureError("must hold a JSON object", file=file)
    try:
        return CaptureManifest.model_validate(raw)
    except ValidationError as exc:
        _raise_validation(exc, CaptureManifest, file=file)
        raise  # unreachable: _raise_validation always raises


def stored_manifest(raw: dict[str, Any]) -> CaptureManifest:
    """A ``capture.json`` the service stored when the capture was created, parsed again.

    It was validated then, perhaps under the laxer rules of the format before 2026-11-24, which kept
    unknown top-level keys beside the known ones: those are read into ``extras``, so that a capture
    acknowledged then is still shown and measured.
    """
    known = {key: value for key, value in raw.items() if key in CaptureManifest.model_fields}
    unknown = {key: value for key, value in raw.items() if key not in CaptureManifest.model_fields}
    return CaptureManifest.model_validate(
        {**known, "extras": {**unknown, **known.get("extras", {})}}, context={_STORED: True}
    )


def parse_camera(data: bytes, *, file: str, view: str | None = None, stored: bool = False) -> CameraModel:
    """Parse and validate the bytes of a view's ``camera.json``.

    ``stored``: the file was accepted earlier (a stored upload), perhaps under the format's rules before
    2026-11-24, which ignored unknown top-level keys and took a missing ``depth_scale`` as
    ``_FORMER_DEPTH_SCALE``; it is read as it was accepted, so that nothing acknowledged then is refused now.
    """
    raw = _load_json(data, file=file, view=view, stored=stored)
    if not isinstance(raw, dict):
        raise CaptureError("must hold a JSON object", file=file, view=view)
    if stored:
        raw = {key: value for key, value in raw.items() if key in _CameraModel.model_fields}
        raw.setdefault("depth_scale", _FORMER_DEPTH_SCALE)
    try:
        model = _CameraModel.model_validate(raw, context={_STORED: stored})
    except ValidationError as exc:
        _raise_validation(exc, _CameraModel, file=file, view=view)
        raise
    return CameraModel(
        depth=Intrinsics(**model.depth_intrinsics.model_dump()),
        depth_scale=model.depth_scale,
        color=Intrinsics(**model.color_intrinsics.model_dump()) if model.color_intrinsics else None,
        depth_to_color=np.asarray(model.depth_to_color, dtype=float) if model.depth_to_color else None,
    )


def capture_time(manifest: CaptureManifest) -> datetime:
    """The capture's ``captured_at`` as an aware datetime.

    Measuring needs no time, so :func:`parse_manifest` accepts any text; whatever orders captures (the
    service, the capture client) needs ISO 8601 with a time zone, and refuses other text with this error.
    """
    try:
        moment = datetime.fromisoformat(manifest.captured_at)
    except ValueError as exc:
        raise CaptureError(
            f"captured_at {manifest.captured_at!r} is not an ISO 8601 time (e.g. 2026-11-20T08:31:00Z)",
            file="capture.json",
            field="captured_at",
        ) from exc
    if moment.tzinfo is None:
        raise CaptureError(
            f"captured_at {manifest.captured_at!r} has no time zone; add Z or an offset such as +02:00",
            file="capture.json",
            field="captured_at",
        )
    return moment


def color_file_names(view: str) -> tuple[str, ...]:
    """The two names a view's colour image may have (PNG or JPEG)."""
    return tuple(f"{view}/{name}" for name in COLOR_NAMES)


def expected_files(manifest: CaptureManifest, received: Collection[str] = ()) -> list[str]:
    """Files a complete capture holds besides capture.json. A view's colour is named as it was
    ``received`` (PNG or JPEG), and by its PNG name while neither has come."""
    expected = []
    for view in manifest.views:
        colors = color_file_names(view)
        color = next((name for name in colors if name in received), colors[0])
        expected += [f"{view}/camera.json", f"{view}/depth.png", color]
    return expected


FileReader = Callable[[str], bytes | None]
"""Returns the bytes of a capture file by its path inside the capture (``views/1/depth.png``), or None
when the capture has no such file. Lets a capture be read from a folder or from the service's store."""


def folder_reader(root: Path) -> FileReader:
    """A :data:`FileReader` over a capture folder on disk."""

    def read(relative: str) -> bytes | None:
        try:
            return (root / relative).read_bytes()
        except FileNotFoundError:
            return None
        except OSError as exc:
            view = relative.rsplit("/", 1)[0] if "/" in relative else None
            raise CaptureError(f"cannot read the file ({exc.strerror})", file=relative, view=view) from exc

    return read


def _required(read: FileReader, relative: str, *, view: str | None) -> bytes:
    data = read(relative)
    if data is None:
        raise CaptureError("file is missing", file=relative, view=view)
    return data


def load_view(
    read: FileReader, name: str, *, max_pixels: int = DEFAULT_MAX_PIXELS, stored: bool = False
) -> View:
    """Load and check one view (``views/<name>``) of a capture through ``read`` (``stored``: files
    accepted earlier, see :func:`parse_camera`)."""
    camera = parse_camera(
        _required(read, f"{name}/camera.json", view=name),
        file=f"{name}/camera.json",
        view=name,
        stored=stored,
    )
    depth = decode_depth(
        _required(read, f"{name}/depth.png", view=name),
        file=f"{name}/depth.png",
        view=name,
        expected_size=camera.depth.size,
        max_pixels=max_pixels,
    )
    present = {file: data for file in color_file_names(name) if (data := read(file)) is not None}
    if not present:
        raise CaptureError(
            "colour image is missing (color.png or color.jpg)", file=f"{name}/color.png", view=name
        )
    if len(present) > 1:
        raise CaptureError(
            "both color.png and color.jpg are present; keep one", file=next(iter(present)), view=name
        )
    [(color_file, color_bytes)] = present.items()
    color = decode_color(
        color_bytes,
        file=color_file,
        view=name,
        expected_size=camera.color_size,
        max_pixels=max_pixels,
        stored=stored,
    )
    return View(name=name, depth_raw=depth, color_rgb=color, camera=camera)


def read_capture(
    manifest: CaptureManifest,
    read: FileReader,
    *,
    root: Path | None = None,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    stored: bool = False,
) -> Capture:
    """Load and validate every view of a capture whose manifest is already parsed (``stored``: files the
    service accepted earlier, see :func:`parse_camera`)."""
    views = tuple(load_view(read, name, max_pixels=max_pixels, stored=stored) for name in manifest.views)
    return Capture(root=root, manifest=manifest, views=views)


def load_capture(path: str | Path, *, max_pixels: int = DEFAULT_MAX_PIXELS) -> Capture:
    """Load and validate a capture folder.

    Parameters
    ----------
    path
        The capture folder (the one holding ``capture.json``).
    max_pixels
        Images with more pixels are refused before decoding.

    Raises
    ------
    CaptureError
        Naming the view, file and field of the first defect found.
    """
    root = Path(path)
    if not root.is_dir():
        raise CaptureError(f"capture folder {root} does not exist or is not a folder")
    read = folder_reader(root)
    manifest = parse_manifest(_required(read, "capture.json", view=None))
    return read_capture(manifest, read, root=root, max_pixels=max_pixels)
