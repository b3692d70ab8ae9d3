"""What was acknowledged survives the server being killed with SIGKILL, and nothing is half-stored."""

from __future__ import annotations

import hashlib
import sqlite3
from pathlib import Path

from tests.service.running import Service, capture_files, content_digest, upload_capture, wait_for_job


def test_acknowledged_files_survive_a_killed_server(service: Service, tree_capture: Path) -> None:
    files = capture_files(tree_capture)
    acknowledged = list(files)[:3]
    with service.client() as client:
        capture_id = client.post("/v1/captures", content=(tree_capture / "capture.json").read_bytes()).json()[
            "id"
        ]
        for path in acknowledged:
            sent = client.put(
                f"/v1/captures/{capture_id}/files/{path}",
                content=files[path],
                headers={"Content-Digest": content_digest(files[path])},
            )
            assert sent.status_code == 201
    service.kill_server()
    service.start_server()
    with service.client() as client:
        capture = client.get(f"/v1/captures/{capture_id}").json()
        again = [
            client.put(
                f"/v1/captures/{capture_id}/files/{path}",
                content=files[path],
                headers={"Content-Digest": content_digest(files[path])},
            ).status_code
            for path in acknowledged
        ]
    assert capture["files_received"] == sorted(acknowledged)
    assert again == [200, 200, 200]
    for path in acknowledged:
        digest = hashlib.sha256(files[path]).hexdigest()
        assert (service.data_dir / "blobs" / digest[:2] / digest).read_bytes() == files[path]


def test_accepted_job_survives_a_killed_server_and_runs(service: Service, tree_capture: Path) -> None:
    with service.client() as client:
        capture_id = upload_capture(client, tree_capture)
        accepted = client.post(f"/v1/captures/{capture_id}/jobs")
    service.kill_server()
    service.start_server()
    service.start_worker()
    with service.client() as client:
        job = wait_for_job(client, accepted.headers["location"])
    assert accepted.status_code == 202
    assert job["state"] == "succeeded"


def test_every_recorded_file_has_its_bytes_in_the_store(service: Service, tree_capture: Path) -> None:
    with service.client() as client:
        upload_capture(client, tree_capture)
    with sqlite3.connect(service.data_dir / "canopy.db") as database:
        records = database.execute("SELECT path, sha256, size_bytes FROM capture_files").fetchall()
    assert len(records) == len(capture_files(tree_capture))
    for _path, digest, size in records:
        blob = (service.data_dir / "blobs" / digest[:2] / digest).read_bytes()
        assert len(blob) == size
        assert hashlib.sha256(blob).hexdigest() == digest
    assert not list((service.data_dir / "blobs").rglob(".incoming-*"))
