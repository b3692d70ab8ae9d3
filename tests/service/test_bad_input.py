"""Bad input over real HTTP: each is answered with a clear 4xx problem+json naming what is wrong, and
nothing of it is stored (DESIGN.md, "Bad input, each answered with a clear 4xx and nothing stored").

Every test makes its own one-view capture of tiny 64x48 registered images, so tests are independent of each
other and of the order they run in; they share one `canopy serve` process.
"""

from __future__ import annotations

import copy
import hashlib
import http.client
import io
import json
import struct
import uuid
import zlib
from collections.abc import Callable, Iterator
from typing import Any
from urllib.parse import urlsplit

import httpx
import numpy as np
import pytest
from PIL import Image

from tests.service.running import Service, content_digest

PROBLEM_JSON = "application/problem+json"
WIDTH, HEIGHT = 64, 48
VIEW = "views/1"
CAMERA: dict[str, Any] = {
    "depth_intrinsics": {"width": WIDTH, "height": HEIGHT, "fx": 50.0, "fy": 50.0, "cx": 32.0, "cy": 24.0},
    "depth_scale": 1000.0,
}
MAX_UPLOAD_BYTES = 4 * 1024 * 1024  # the shared_service's limit
DEFAULT_MAX_IMAGE_PIXELS = 40_000_000  # the shared_service keeps the default
MANIFEST_LIMIT_BYTES = 1024 * 1024


# --- tiny files -----------------------------------------------------------------------------------------


def encode(pixels: np.ndarray, image_format: str = "PNG") -> bytes:
    """``pixels`` encoded as a PNG or JPEG file."""
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, image_format)
    return buffer.getvalue()


def depth_png(width: int = WIDTH, height: int = HEIGHT, depth_mm: int = 2000) -> bytes:
    """A valid 16-bit single-channel depth PNG of constant depth."""
    return encode(np.full((height, width), depth_mm, dtype=np.uint16))


def color_image(width: int = WIDTH, height: int = HEIGHT, image_format: str = "PNG") -> bytes:
    """A valid 8-bit RGB colour image with some texture (so a JPEG has real entropy-coded data)."""
    pixels = np.random.default_rng(7).integers(0, 256, (height, width, 3), dtype=np.uint8)
    return encode(pixels, image_format)


def camera_json(camera: dict[str, Any] = CAMERA) -> bytes:
    """camera.json's bytes; NaN and Infinity are written literally, as careless exporters do."""
    return json.dumps(camera).encode()


def camera_of_size(width: int, height: int) -> dict[str, Any]:
    """The test camera, with depth intrinsics for an image of ``width`` x ``height`` (the same field of
    view: focal lengths scaled with the width)."""
    camera = copy.deepcopy(CAMERA)
    focal = CAMERA["depth_intrinsics"]["fx"] * width / CAMERA["depth_intrinsics"]["width"]
    camera["depth_intrinsics"].update(
        width=width, height=height, fx=focal, fy=focal, cx=width / 2, cy=height / 2
    )
    return camera


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def grey_png(width: int, height: int, idat: bytes) -> bytes:
    """An 8-bit greyscale PNG with this header and these (already compressed) image data."""
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + _png_chunk(b"IHDR", header)
        + _png_chunk(b"IDAT", idat)
        + _png_chunk(b"IEND", b"")
    )


def all_zero_png(width: int, height: int) -> bytes:
    """A complete, valid all-zero greyscale PNG; zeros compress about 1000:1, so it is small."""
    compressor = zlib.compressobj(9)
    rows_per_piece = 500
    piece = b"\x00" * ((width + 1) * rows_per_piece)  # each row: filter byte 0, then the pixels
    parts = [compressor.compress(piece) for _ in range(height // rows_per_piece)]
    parts.append(compressor.compress(b"\x00" * ((width + 1) * (height % rows_per_piece))))
    parts.append(compressor.flush())
    return grey_png(width, height, b"".join(parts))


# --- talking to the service ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def client(shared_service: Service) -> Iterator[httpx.Client]:
    """An admin client of the module's service."""
    with shared_service.client() as admin:
        yield admin


def manifest(**changes: Any) -> dict[str, Any]:
    """A valid one-view capture.json in an orchard of its own (unique per call), with ``changes``."""
    unique = uuid.uuid4().hex[:12]
    document: dict[str, Any] = {
        "format": "canopy-capture/1",
        "orchard": f"Bad input {unique}",
        "row": "R1",
        "tree": f"T-{unique}",
        "captured_at": "2026-11-20T08:31:00Z",
        "sensor": "kinect-v2",
        "calibration_balls": {"diameter_m": 0.10, "colors": ["red", "yellow", "blue"]},
        "views": [VIEW],
    }
    document.update(changes)
    return document


@pytest.fixture
def capture_id(client: httpx.Client) -> int:
    """A new, empty one-view capture of its own tree."""
    created = client.post("/v1/captures", json=manifest())
    assert created.status_code == 201, created.text
    return int(created.json()["id"])


def put_file(
    client: httpx.Client, capture_id: int, path: str, data: bytes, *, digest: str | None = "auto"
) -> httpx.Response:
    """PUT one file; ``digest`` is the Content-Digest to send ("auto": the right one, None: none)."""
    headers = (
        {} if digest is None else {"Content-Digest": content_digest(data) if digest == "auto" else digest}
    )
    return client.put(f"/v1/captures/{capture_id}/files/{path}", content=data, headers=headers)


def stored(client: httpx.Client, capture_id: int, path: str, data: bytes) -> dict[str, Any]:
    """PUT a file that must be accepted; its record."""
    response = put_file(client, capture_id, path, data)
    assert response.status_code == 201, response.text
    return dict(response.json())


def files_received(client: httpx.Client, capture_id: int) -> list[str]:
    response = client.get(f"/v1/captures/{capture_id}")
    assert response.status_code == 200, response.text
    return list(response.json()["files_received"])


def orchard_names(client: httpx.Client) -> set[str]:
    """Every orchard's name, over all pages."""
    names: set[str] = set()
    cursor: str | None = None
    while True:
        params = {"limit": 1000, **({"cursor": cursor} if cursor else {})}
        response = client.get("/v1/orchards", params=params)
        assert response.status_code == 200, response.text
        page = response.json()
        names.update(item["name"] for item in page["items"])
        cursor = page["next_cursor"]
        if cursor is None:
            return names


def assert_problem(response: httpx.Response, status: int, **members: Any) -> dict[str, Any]:
    """``response`` is an RFC 9457 problem of ``status`` holding ``members``; its body."""
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith(PROBLEM_JSON)
    body = dict(response.json())
    for key in ("type", "title", "status", "detail"):
        assert key in body, f"problem without {key}: {body}"
    assert body["status"] == status
    assert isinstance(body["detail"], str) and body["detail"]
    for key, value in members.items():
        assert body.get(key) == value, f"{key}: {body.get(key)!r} != {value!r} in {body}"
    return body


def assert_refused_upload(
    client: httpx.Client,
    capture_id: int,
    response: httpx.Response,
    path: str,
    status: int = 422,
    **members: Any,
) -> dict[str, Any]:
    """The upload of ``path`` was refused with a problem naming it, and the capture does not hold it."""
    body = assert_problem(response, status, **members)
    assert path not in files_received(client, capture_id)
    return body


# --- corrupt, truncated and wrongly typed images ----------------------------------------------------------


def test_corrupt_png_depth_is_refused_and_not_stored(client: httpx.Client, capture_id: int) -> None:
    damaged = bytearray(depth_png())
    start = damaged.index(b"IDAT") + 6  # inside the compressed pixel data
    damaged[start : start + 14] = b"\x55" * 14
    response = put_file(client, capture_id, "views/1/depth.png", bytes(damaged))
    body = assert_refused_upload(
        client, capture_id, response, "views/1/depth.png", file="views/1/depth.png", view=VIEW
    )
    assert "corrupt" in body["detail"]


def test_bytes_that_are_no_image_are_refused_and_not_stored(client: httpx.Client, capture_id: int) -> None:
    response = put_file(client, capture_id, "views/1/color.png", b"this is not an image at all")
    assert_refused_upload(
        client, capture_id, response, "views/1/color.png", file="views/1/color.png", view=VIEW
    )


def test_truncated_png_depth_is_refused_and_not_stored(client: httpx.Client, capture_id: int) -> None:
    whole = depth_png()
    response = put_file(client, capture_id, "views/1/depth.png", whole[: len(whole) // 2])
    body = assert_refused_upload(
        client, capture_id, response, "views/1/depth.png", file="views/1/depth.png", view=VIEW
    )
    assert "truncated" in body["detail"]


def test_truncated_jpeg_colour_is_refused_and_not_stored(client: httpx.Client, capture_id: int) -> None:
    whole = color_image(image_format="JPEG")
    response = put_file(client, capture_id, "views/1/color.jpg", whole[: len(whole) // 2])
    body = assert_refused_upload(
        client, capture_id, response, "views/1/color.jpg", file="views/1/color.jpg", view=VIEW
    )
    assert "truncated" in body["detail"]


def test_corrupt_jpeg_colour_is_refused_and_not_stored(client: httpx.Client, capture_id: int) -> None:
    damaged = bytearray(color_image(image_format="JPEG"))
    huffman_table = damaged.index(b"\xff\xc4")
    damaged[huffman_table + 4 : huffman_table + 30] = b"\xff" * 26
    response = put_file(client, capture_id, "views/1/color.jpg", bytes(damaged))
    body = assert_refused_upload(
        client, capture_id, response, "views/1/color.jpg", file="views/1/color.jpg", view=VIEW
    )
    assert "corrupt" in body["detail"]


def test_depth_that_is_8_bit_is_refused_and_not_stored(client: httpx.Client, capture_id: int) -> None:
    eight_bit = encode(np.full((HEIGHT, WIDTH), 200, dtype=np.uint8))
    response = put_file(client, capture_id, "views/1/depth.png", eight_bit)
    body = assert_refused_upload(
        client, capture_id, response, "views/1/depth.png", file="views/1/depth.png", view=VIEW
    )
    assert "16-bit" in body["detail"]


def test_depth_that_is_rgb_is_refused_and_not_stored(client: httpx.Client, capture_id: int) -> None:
    response = put_file(client, capture_id, "views/1/depth.png", color_image())
    body = assert_refused_upload(
        client, capture_id, response, "views/1/depth.png", file="views/1/depth.png", view=VIEW
    )
    assert "16-bit single-channel" in body["detail"]


def test_depth_that_is_a_jpeg_is_refused_and_not_stored(client: httpx.Client, capture_id: int) -> None:
    response = put_file(client, capture_id, "views/1/depth.png", color_image(image_format="JPEG"))
    body = assert_refused_upload(
        client, capture_id, response, "views/1/depth.png", file="views/1/depth.png", view=VIEW
    )
    assert "PNG" in body["detail"]


def test_colour_that_is_greyscale_is_refused_and_not_stored(client: httpx.Client, capture_id: int) -> None:
    grey = encode(np.full((HEIGHT, WIDTH), 128, dtype=np.uint8))
    response = put_file(client, capture_id, "views/1/color.png", grey)
    body = assert_refused_upload(
        client, capture_id, response, "views/1/color.png", file="views/1/color.png", view=VIEW
    )
    assert "RGB" in body["detail"]


def test_depth_with_no_valid_pixel_is_refused_and_not_stored(client: httpx.Client, capture_id: int) -> None:
    response = put_file(client, capture_id, "views/1/depth.png", depth_png(depth_mm=0))
    body = assert_refused_upload(
        client, capture_id, response, "views/1/depth.png", file="views/1/depth.png", view=VIEW
    )
    assert "no valid pixel" in body["detail"]


# --- sizes that disagree with camera.json -----------------------------------------------------------------


def test_depth_smaller_than_camera_says_is_refused_when_camera_came_first(
    client: httpx.Client, capture_id: int
) -> None:
    stored(client, capture_id, "views/1/camera.json", camera_json())
    response = put_file(client, capture_id, "views/1/depth.png", depth_png(32, 24))
    body = assert_refused_upload(
        client, capture_id, response, "views/1/depth.png", file="views/1/depth.png", view=VIEW
    )
    assert "32x24" in body["detail"] and f"{WIDTH}x{HEIGHT}" in body["detail"]
    assert files_received(client, capture_id) == ["views/1/camera.json"]


def test_camera_disagreeing_with_stored_depth_is_refused_when_depth_came_first(
    client: httpx.Client, capture_id: int
) -> None:
    stored(client, capture_id, "views/1/depth.png", depth_png())
    response = put_file(client, capture_id, "views/1/camera.json", camera_json(camera_of_size(128, 96)))
    body = assert_refused_upload(
        client,
        capture_id,
        response,
        "views/1/camera.json",
        file="views/1/camera.json",
        view=VIEW,
        field="depth_intrinsics",
    )
    assert "128x96" in body["detail"]
    assert files_received(client, capture_id) == ["views/1/depth.png"]


def test_colour_of_another_size_than_registered_depth_is_refused_when_camera_came_first(
    client: httpx.Client, capture_id: int
) -> None:
    stored(client, capture_id, "views/1/camera.json", camera_json())
    response = put_file(client, capture_id, "views/1/color.png", color_image(32, 24))
    body = assert_refused_upload(
        client, capture_id, response, "views/1/color.png", file="views/1/color.png", view=VIEW
    )
    assert "32x24" in body["detail"]


def test_camera_disagreeing_with_stored_colour_is_refused_when_colour_came_first(
    client: httpx.Client, capture_id: int
) -> None:
    stored(client, capture_id, "views/1/color.jpg", color_image(image_format="JPEG"))
    response = put_file(client, capture_id, "views/1/camera.json", camera_json(camera_of_size(128, 96)))
    assert_refused_upload(
        client, capture_id, response, "views/1/camera.json", file="views/1/camera.json", view=VIEW
    )
    assert files_received(client, capture_id) == ["views/1/color.jpg"]


def test_colour_disagreeing_with_native_colour_intrinsics_is_refused(
    client: httpx.Client, capture_id: int
) -> None:
    native = {
        **CAMERA,
        "color_intrinsics": {"width": 128, "height": 96, "fx": 100.0, "fy": 100.0, "cx": 64.0, "cy": 48.0},
        "depth_to_color": [[1, 0, 0, 0.052], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
    }
    stored(client, capture_id, "views/1/camera.json", camera_json(native))
    response = put_file(client, capture_id, "views/1/color.png", color_image(WIDTH, HEIGHT))
    body = assert_refused_upload(
        client, capture_id, response, "views/1/color.png", file="views/1/color.png", view=VIEW
    )
    assert "128x96" in body["detail"]


# --- camera.json intrinsics ------------------------------------------------------------------------------


def _without_fx(camera: dict[str, Any]) -> None:
    del camera["depth_intrinsics"]["fx"]


def _set(field: str, value: float) -> Callable[[dict[str, Any]], None]:
    def change(camera: dict[str, Any]) -> None:
        camera["depth_intrinsics"][field] = value

    return change


@pytest.mark.parametrize(
    ("change", "field"),
    [
        pytest.param(_without_fx, "depth_intrinsics.fx", id="missing-fx"),
        pytest.param(_set("fx", 0.0), "depth_intrinsics.fx", id="zero-fx"),
        pytest.param(_set("fy", -50.0), "depth_intrinsics.fy", id="negative-fy"),
        pytest.param(_set("width", 0), "depth_intrinsics.width", id="zero-width"),
        pytest.param(_set("height", -48), "depth_intrinsics.height", id="negative-height"),
        pytest.param(_set("cx", float("nan")), "depth_intrinsics.cx", id="nan-cx"),
        pytest.param(_set("fx", float("inf")), "depth_intrinsics.fx", id="infinite-fx"),
        pytest.param(_set("cy", float("-inf")), "depth_intrinsics.cy", id="minus-infinite-cy"),
    ],
)
def test_camera_with_bad_intrinsics_is_refused_naming_the_field(
    client: httpx.Client, capture_id: int, change: Callable[[dict[str, Any]], None], field: str
) -> None:
    camera = copy.deepcopy(CAMERA)
    change(camera)
    data = camera_json(camera)
    response = put_file(client, capture_id, "views/1/camera.json", data)
    assert_refused_upload(
        client,
        capture_id,
        response,
        "views/1/camera.json",
        file="views/1/camera.json",
        view=VIEW,
        field=field,
    )


def test_camera_with_a_misspelt_key_is_refused_naming_the_key_meant(
    client: httpx.Client, capture_id: int
) -> None:
    """Taken as absent, a misspelt depth_scale would have measured with a default scale: wrong metres."""
    camera = copy.deepcopy(CAMERA)
    camera["depth_scael"] = camera.pop("depth_scale")
    response = put_file(client, capture_id, "views/1/camera.json", camera_json(camera))
    body = assert_refused_upload(
        client,
        capture_id,
        response,
        "views/1/camera.json",
        file="views/1/camera.json",
        view=VIEW,
        field="depth_scael",
    )
    assert "did you mean 'depth_scale'?" in body["detail"]


def test_non_finite_intrinsics_are_sent_as_literal_json_tokens() -> None:
    # Guards the parametrised test above: the service must see NaN and Infinity, not strings or nulls.
    camera = copy.deepcopy(CAMERA)
    camera["depth_intrinsics"].update(cx=float("nan"), fx=float("inf"), cy=float("-inf"))
    text = camera_json(camera).decode()
    assert '"cx": NaN' in text and '"fx": Infinity' in text and '"cy": -Infinity' in text


def test_camera_json_that_is_not_json_is_refused_and_not_stored(
    client: httpx.Client, capture_id: int
) -> None:
    response = put_file(client, capture_id, "views/1/camera.json", b'{"depth_intrinsics": {')
    body = assert_refused_upload(
        client, capture_id, response, "views/1/camera.json", file="views/1/camera.json", view=VIEW
    )
    assert "JSON" in body["detail"]


# --- paths outside the capture ---------------------------------------------------------------------------


def test_percent_encoded_dot_dot_path_reaches_the_server_and_is_refused(
    shared_service: Service, client: httpx.Client, capture_id: int
) -> None:
    data = b"root:x:0:0"
    url = httpx.URL(f"{shared_service.url}/v1/captures/{capture_id}/files/views/1/%2E%2E/%2E%2E/etc/passwd")
    assert b"/%2E%2E/%2E%2E/" in url.raw_path  # httpx sends the segments as written, not normalised away
    response = client.put(url, content=data, headers={"Content-Digest": content_digest(data)})
    assert_problem(response, 422, code="invalid_path", file="views/1/../../etc/passwd")
    assert files_received(client, capture_id) == []


def test_literal_dot_dot_path_is_refused(
    shared_service: Service, client: httpx.Client, capture_id: int
) -> None:
    # httpx would normalise a literal '..' away on the client side; http.client sends the target verbatim.
    data = b"root:x:0:0"
    address = urlsplit(shared_service.url)
    connection = http.client.HTTPConnection(address.hostname or "127.0.0.1", address.port, timeout=30)
    try:
        connection.request(
            "PUT",
            f"/v1/captures/{capture_id}/files/views/1/../../../capture.json",
            body=data,
            headers={
                "Authorization": f"Bearer {shared_service.admin_key}",
                "Content-Digest": content_digest(data),
            },
        )
        answer = connection.getresponse()
        status, content_type, body = (
            answer.status,
            answer.getheader("content-type", ""),
            json.loads(answer.read()),
        )
    finally:
        connection.close()
    assert status == 422 and content_type.startswith(PROBLEM_JSON)
    assert body["code"] == "invalid_path" and body["file"] == "views/1/../../../capture.json"
    assert {"type", "title", "status", "detail"} <= body.keys()
    assert files_received(client, capture_id) == []


def test_absolute_path_is_refused(client: httpx.Client, capture_id: int) -> None:
    response = put_file(client, capture_id, "%2Fetc%2Fpasswd", b"root:x:0:0")
    assert_problem(response, 422, code="invalid_path", file="/etc/passwd")
    assert files_received(client, capture_id) == []


def test_unknown_file_name_in_a_view_is_refused(client: httpx.Client, capture_id: int) -> None:
    response = put_file(client, capture_id, "views/1/notes.txt", b"field notes")
    assert_problem(response, 422, code="invalid_path", file="views/1/notes.txt")
    assert files_received(client, capture_id) == []


def test_file_of_a_view_the_capture_does_not_list_is_refused(client: httpx.Client, capture_id: int) -> None:
    response = put_file(client, capture_id, "views/9/depth.png", depth_png())
    body = assert_problem(response, 422, code="invalid_path", file="views/9/depth.png")
    assert VIEW in body["detail"]
    assert files_received(client, capture_id) == []


def test_path_with_backslashes_is_refused(client: httpx.Client, capture_id: int) -> None:
    response = put_file(client, capture_id, "views%5C1%5Cdepth.png", depth_png())
    assert_problem(response, 422, code="invalid_path", file="views\\1\\depth.png")
    assert files_received(client, capture_id) == []


def test_path_with_an_empty_segment_is_refused(client: httpx.Client, capture_id: int) -> None:
    stored(client, capture_id, "views/1/depth.png", depth_png(depth_mm=2000))
    response = put_file(client, capture_id, "views/1//depth.png", depth_png(depth_mm=2500))
    assert_problem(response, 422, code="invalid_path", file="views/1//depth.png")
    assert files_received(client, capture_id) == ["views/1/depth.png"]


def test_path_with_a_trailing_slash_is_refused(client: httpx.Client, capture_id: int) -> None:
    stored(client, capture_id, "views/1/color.jpg", color_image(image_format="JPEG"))
    response = put_file(client, capture_id, "views/1/color.png/", color_image())
    assert_problem(response, 422, code="invalid_path", file="views/1/color.png/")
    assert files_received(client, capture_id) == ["views/1/color.jpg"]


def test_ground_truth_is_not_a_file_the_service_accepts(client: httpx.Client, capture_id: int) -> None:
    response = put_file(client, capture_id, "ground_truth.json", b"{}")
    assert_problem(response, 422, code="invalid_path", file="ground_truth.json")
    assert files_received(client, capture_id) == []


# --- Content-Digest --------------------------------------------------------------------------------------


def test_digest_that_does_not_match_the_body_is_refused_and_not_stored(
    client: httpx.Client, capture_id: int
) -> None:
    data = depth_png()
    response = put_file(client, capture_id, "views/1/depth.png", data, digest=content_digest(data + b"x"))
    assert_refused_upload(
        client,
        capture_id,
        response,
        "views/1/depth.png",
        400,
        code="digest_mismatch",
        file="views/1/depth.png",
        field="Content-Digest",
    )


def test_missing_digest_is_refused_and_not_stored(client: httpx.Client, capture_id: int) -> None:
    response = put_file(client, capture_id, "views/1/depth.png", depth_png(), digest=None)
    assert_refused_upload(
        client, capture_id, response, "views/1/depth.png", 400, code="digest_missing", field="Content-Digest"
    )


@pytest.mark.parametrize(
    "header",
    [
        pytest.param("sha-256=:bm90IGEgZGlnZXN0:", id="too-short"),
        pytest.param("sha-256=:***:", id="not-base64"),
        pytest.param("md5=:1B2M2Y8AsgTpgAmY7PhCfg==:", id="no-sha-256-member"),
    ],
)
def test_unusable_digest_is_refused_and_not_stored(
    client: httpx.Client, capture_id: int, header: str
) -> None:
    response = put_file(client, capture_id, "views/1/depth.png", depth_png(), digest=header)
    assert_refused_upload(
        client, capture_id, response, "views/1/depth.png", 400, code="digest_invalid", field="Content-Digest"
    )


# --- size limits -----------------------------------------------------------------------------------------


def test_body_over_the_limit_with_honest_content_length_is_refused_and_not_stored(
    client: httpx.Client, capture_id: int
) -> None:
    data = b"\x00" * (MAX_UPLOAD_BYTES + 1)
    response = put_file(client, capture_id, "views/1/depth.png", data)
    assert response.request.headers["content-length"] == str(len(data))
    assert_refused_upload(
        client,
        capture_id,
        response,
        "views/1/depth.png",
        413,
        code="body_too_large",
        file="views/1/depth.png",
        limit_bytes=MAX_UPLOAD_BYTES,
    )


def test_body_over_the_limit_sent_chunked_is_refused_and_not_stored(
    client: httpx.Client, capture_id: int
) -> None:
    piece, pieces = b"\x00" * (1024 * 1024), 5

    def chunks() -> Iterator[bytes]:
        yield from [piece] * pieces

    response = client.put(
        f"/v1/captures/{capture_id}/files/views/1/depth.png",
        content=chunks(),
        headers={"Content-Digest": content_digest(piece * pieces)},
    )
    assert response.request.headers["transfer-encoding"] == "chunked"
    assert "content-length" not in response.request.headers
    assert_refused_upload(
        client,
        capture_id,
        response,
        "views/1/depth.png",
        413,
        code="body_too_large",
        file="views/1/depth.png",
        limit_bytes=MAX_UPLOAD_BYTES,
    )


@pytest.fixture(scope="module")
def decompression_bomb() -> bytes:
    """A complete, valid 10000x5000 greyscale PNG (50 Mpx, over the 40 Mpx limit) of about 50 kB."""
    bomb = all_zero_png(10_000, 5_000)
    assert len(bomb) < 100_000
    return bomb


def test_image_over_the_pixel_limit_is_refused_and_not_stored(
    client: httpx.Client, capture_id: int, decompression_bomb: bytes
) -> None:
    response = put_file(client, capture_id, "views/1/color.png", decompression_bomb)
    body = assert_refused_upload(
        client, capture_id, response, "views/1/color.png", file="views/1/color.png", view=VIEW
    )
    assert "10000x5000" in body["detail"] and str(DEFAULT_MAX_IMAGE_PIXELS) in body["detail"]


def test_image_over_the_pixel_limit_is_refused_from_its_header_alone(
    client: httpx.Client, capture_id: int
) -> None:
    # Only the header is real: decoding would fail as truncated, so a pixel-limit answer proves the header
    # was judged before any pixel was decoded.
    header_only = grey_png(20_000, 20_000, zlib.compress(b"\x00" * 64))
    response = put_file(client, capture_id, "views/1/depth.png", header_only)
    body = assert_refused_upload(
        client, capture_id, response, "views/1/depth.png", file="views/1/depth.png", view=VIEW
    )
    assert "20000x20000" in body["detail"] and "exceeds the limit" in body["detail"]


# --- capture.json ----------------------------------------------------------------------------------------


def assert_capture_refused(
    client: httpx.Client, content: bytes, orchard: str, **members: Any
) -> dict[str, Any]:
    """POSTing ``content`` as capture.json is a 422 naming ``members``, and creates no orchard."""
    before = orchard_names(client)
    response = client.post("/v1/captures", content=content, headers={"Content-Type": "application/json"})
    body = assert_problem(response, 422, file="capture.json", **members)
    after = orchard_names(client)
    assert orchard not in after
    assert after == before
    return body


def test_capture_json_that_is_not_json_is_refused_and_creates_nothing(client: httpx.Client) -> None:
    document = manifest()
    text = json.dumps(document)[:-10]  # cut off mid-way
    body = assert_capture_refused(client, text.encode(), document["orchard"])
    assert "JSON" in body["detail"]


def test_capture_json_that_is_not_an_object_is_refused_and_creates_nothing(client: httpx.Client) -> None:
    document = manifest()
    assert_capture_refused(client, json.dumps([document]).encode(), document["orchard"])


def test_capture_json_of_another_format_is_refused_and_creates_nothing(client: httpx.Client) -> None:
    document = manifest(format="canopy-capture/2")
    body = assert_capture_refused(client, json.dumps(document).encode(), document["orchard"], field="format")
    assert "canopy-capture/1" in body["detail"]


def test_capture_json_missing_a_field_is_refused_and_creates_nothing(client: httpx.Client) -> None:
    document = manifest()
    del document["tree"]
    assert_capture_refused(client, json.dumps(document).encode(), document["orchard"], field="tree")


def test_capture_time_without_time_zone_is_refused_and_creates_nothing(client: httpx.Client) -> None:
    document = manifest(captured_at="2026-11-20T08:31:00")
    body = assert_capture_refused(
        client, json.dumps(document).encode(), document["orchard"], field="captured_at"
    )
    assert "time zone" in body["detail"]


def test_capture_time_that_is_no_time_is_refused_and_creates_nothing(client: httpx.Client) -> None:
    document = manifest(captured_at="yesterday morning")
    assert_capture_refused(client, json.dumps(document).encode(), document["orchard"], field="captured_at")


def test_capture_json_over_its_size_limit_is_refused_and_creates_nothing(client: httpx.Client) -> None:
    document = manifest()
    padded = json.dumps(document).encode() + b" " * MANIFEST_LIMIT_BYTES  # valid JSON, if it were read
    before = orchard_names(client)
    response = client.post("/v1/captures", content=padded, headers={"Content-Type": "application/json"})
    assert_problem(
        response, 413, code="body_too_large", file="capture.json", limit_bytes=MANIFEST_LIMIT_BYTES
    )
    assert orchard_names(client) == before


@pytest.mark.parametrize("view", ["../x", "views/../../x", "/views/1", "views/1/deeper", "other/1"])
def test_view_path_outside_the_views_folder_is_refused_and_creates_nothing(
    client: httpx.Client, view: str
) -> None:
    document = manifest(views=[view])
    body = assert_capture_refused(client, json.dumps(document).encode(), document["orchard"], field="views")
    assert view in body["detail"]


# --- conflicts with what is stored -----------------------------------------------------------------------


def test_same_bytes_sent_again_are_acknowledged_with_200(client: httpx.Client, capture_id: int) -> None:
    data = depth_png()
    first = stored(client, capture_id, "views/1/depth.png", data)
    again = put_file(client, capture_id, "views/1/depth.png", data)
    assert again.status_code == 200, again.text
    assert again.json()["sha256"] == first["sha256"]
    assert files_received(client, capture_id) == ["views/1/depth.png"]


def test_different_bytes_for_a_stored_path_conflict_and_the_original_is_kept(
    client: httpx.Client, capture_id: int
) -> None:
    original = depth_png(depth_mm=2000)
    first = stored(client, capture_id, "views/1/depth.png", original)
    response = put_file(client, capture_id, "views/1/depth.png", depth_png(depth_mm=2500))
    assert_problem(response, 409, code="file_conflict", file="views/1/depth.png", view=VIEW)
    assert first["sha256"] in response.json()["detail"]
    kept = put_file(client, capture_id, "views/1/depth.png", original)
    assert kept.status_code == 200 and kept.json()["sha256"] == first["sha256"]


def test_jpeg_colour_after_png_colour_of_the_same_view_conflicts(
    client: httpx.Client, capture_id: int
) -> None:
    stored(client, capture_id, "views/1/color.png", color_image())
    response = put_file(client, capture_id, "views/1/color.jpg", color_image(image_format="JPEG"))
    assert_problem(response, 409, code="file_conflict", file="views/1/color.jpg", view=VIEW)
    assert files_received(client, capture_id) == ["views/1/color.png"]


# --- jobs ------------------------------------------------------------------------------------------------


def jobs_of(client: httpx.Client, capture_id: int) -> list[dict[str, Any]]:
    response = client.get("/v1/jobs", params={"capture_id": capture_id})
    assert response.status_code == 200, response.text
    return list(response.json()["items"])


def test_job_for_a_capture_with_files_missing_conflicts_listing_them(
    client: httpx.Client, capture_id: int
) -> None:
    stored(client, capture_id, "views/1/camera.json", camera_json())
    response = client.post(f"/v1/captures/{capture_id}/jobs")
    body = assert_problem(response, 409, code="files_missing")
    assert body["missing"] == ["views/1/depth.png", "views/1/color.png"]
    assert jobs_of(client, capture_id) == []


@pytest.mark.parametrize(
    ("config", "field"),
    [
        pytest.param({"roi": {"radius_m": -1}}, "config.roi.radius_m", id="negative-radius"),
        pytest.param({"roi": {"radius": 2.0}}, "config.roi.radius", id="unknown-setting"),
        pytest.param({"filters": {"min_depth_m": "near"}}, "config.filters.min_depth_m", id="not-a-number"),
    ],
)
def test_job_with_invalid_config_override_is_refused_naming_the_field_and_not_created(
    client: httpx.Client, capture_id: int, config: dict[str, Any], field: str
) -> None:
    stored(client, capture_id, "views/1/camera.json", camera_json())
    stored(client, capture_id, "views/1/depth.png", depth_png())
    stored(client, capture_id, "views/1/color.png", color_image())
    response = client.post(f"/v1/captures/{capture_id}/jobs", json={"config": config})
    assert_problem(response, 422, field=field)
    assert jobs_of(client, capture_id) == []


def test_job_with_an_infinite_setting_is_refused_naming_it_and_not_created(
    client: httpx.Client, capture_id: int
) -> None:
    """Python's JSON reads Infinity and NaN; the results are strict JSON, so a setting cannot be either."""
    stored(client, capture_id, "views/1/camera.json", camera_json())
    stored(client, capture_id, "views/1/depth.png", depth_png())
    stored(client, capture_id, "views/1/color.png", color_image())
    for value in ("Infinity", "NaN"):
        response = client.post(
            f"/v1/captures/{capture_id}/jobs",
            content=f'{{"config": {{"metrics": {{"max_thin_top_m": {value}}}}}}}',
            headers={"Content-Type": "application/json"},
        )
        assert_problem(response, 422, field="config.metrics.max_thin_top_m")
    assert jobs_of(client, capture_id) == []


# --- the blob store --------------------------------------------------------------------------------------


def test_refused_depth_of_the_wrong_size_leaves_no_blob_in_the_store(
    shared_service: Service, client: httpx.Client, capture_id: int
) -> None:
    stored(client, capture_id, "views/1/camera.json", camera_json())
    wrong_size = depth_png(32, 24, depth_mm=1234)
    response = put_file(client, capture_id, "views/1/depth.png", wrong_size)
    assert_refused_upload(client, capture_id, response, "views/1/depth.png", file="views/1/depth.png")
    sha256 = hashlib.sha256(wrong_size).hexdigest()
    assert not (shared_service.data_dir / "blobs" / sha256[:2] / sha256).exists()
