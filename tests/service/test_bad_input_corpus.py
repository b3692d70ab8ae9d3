"""The generated bad-input corpus (tests/bad_inputs.py), each kind both ways a user meets it: given to
`canopy measure` (exit 2 and one line naming the file) and sent over HTTP as `canopy upload` would (one
4xx problem+json naming the file, and nothing of it stored). Then what a hostile client sends below the
files: ids past 64 bits, a negative Content-Length, a header that is not one."""

from __future__ import annotations

import json
import socket
import sqlite3
import subprocess
import uuid
from pathlib import Path

import pytest

from tests.bad_inputs import BAD_INPUTS, BadInput, write_corpus
from tests.service.running import CANOPY, Service, content_digest

PROBLEM_JSON = "application/problem+json"


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return write_corpus(tmp_path_factory.mktemp("corpus"))


def _captures(service: Service) -> int:
    with sqlite3.connect(service.data_dir / "canopy.db") as database:
        return int(database.execute("SELECT COUNT(*) FROM captures").fetchone()[0])


@pytest.mark.parametrize("bad", BAD_INPUTS, ids=[bad.kind for bad in BAD_INPUTS])
def test_canopy_measure_refuses_it_in_one_line_naming_the_file(
    bad: BadInput, corpus: dict[str, Path]
) -> None:
    done = subprocess.run(
        [CANOPY, "measure", str(corpus[bad.kind])], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.startswith(f"error: {bad.rename_to or bad.path}: ")
    assert bad.says in done.stderr


@pytest.mark.parametrize("bad", BAD_INPUTS, ids=[bad.kind for bad in BAD_INPUTS])
def test_the_service_refuses_it_with_one_4xx_naming_the_file_and_stores_nothing_of_it(
    bad: BadInput, corpus: dict[str, Path], shared_service: Service
) -> None:
    folder = corpus[bad.kind]
    bad_path = bad.rename_to or bad.path
    manifest = (folder / "capture.json").read_bytes()
    if bad.path != "capture.json":  # a tree of its own on the shared service
        manifest = json.dumps({**json.loads(manifest), "tree": f"corpus-{uuid.uuid4().hex[:8]}"}).encode()
    captures_before = _captures(shared_service)
    answers = {}
    with shared_service.client() as client:
        created = client.post("/v1/captures", content=manifest)
        answers["capture.json"] = created
        if created.status_code == 201:
            capture_id = created.json()["id"]
            for path in (
                "views/1/camera.json",
                "views/1/depth.png",
                "views/1/color.png",
                "views/1/color.jpg",
            ):
                if (folder / path).is_file():
                    data = (folder / path).read_bytes()
                    answers[path] = client.put(
                        f"/v1/captures/{capture_id}/files/{path}",
                        content=data,
                        headers={"Content-Digest": content_digest(data)},
                    )
            received = client.get(f"/v1/captures/{capture_id}").json()["files_received"]
    refused = {path: answer for path, answer in answers.items() if answer.status_code >= 400}
    assert list(refused) == [bad_path], {path: answer.text for path, answer in answers.items()}
    answer = refused[bad_path]
    assert 400 <= answer.status_code < 500
    assert answer.headers["content-type"] == PROBLEM_JSON
    assert answer.json()["file"] == bad_path
    assert bad.says in answer.json()["detail"], answer.json()
    if bad_path == "capture.json":
        assert _captures(shared_service) == captures_before
    else:
        assert bad_path not in received and len(received) == len(answers) - 2


def _raw(service: Service, request: bytes) -> bytes:
    port = int(service.url.rsplit(":", 1)[1])
    with socket.create_connection(("127.0.0.1", port), timeout=30) as connection:
        connection.sendall(request)
        received = b""
        while chunk := connection.recv(65536):
            received += chunk
    return received


@pytest.mark.parametrize(
    "request_head",
    [
        b"PUT /v1/captures/1/files/views/1/depth.png HTTP/1.1\r\nHost: x\r\nContent-Length: -1\r\n\r\n",
        b"GET /v1/orchards HTTP/1.1\r\nHost: x\r\nthis header has no colon\r\n\r\n",
        b"GET /v1/orchards HTTP/1.1\r\nHost: x\r\nContent-Length: 1\r\nContent-Length: 2\r\n\r\n",
    ],
    ids=["negative_content_length", "header_without_colon", "two_content_lengths"],
)
def test_a_request_that_is_not_http_gets_a_problem_json_400_and_the_connection_closed(
    shared_service: Service, request_head: bytes
) -> None:
    answer = _raw(shared_service, request_head)
    head, _, body = answer.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 400 "), answer
    assert b"content-type: application/problem+json" in head.lower()
    assert b"connection: close" in head.lower()
    assert json.loads(body)["code"] == "malformed_request"


@pytest.mark.parametrize("path", ["/v1/jobs/9223372036854775808", "/v1/captures/18446744073709551616"])
def test_ids_past_64_bits_are_a_4xx_not_a_500(shared_service: Service, path: str) -> None:
    with shared_service.client() as client:
        answer = client.get(path)
    assert answer.status_code == 422, answer.text
    assert answer.headers["content-type"] == PROBLEM_JSON
