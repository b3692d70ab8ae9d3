"""`canopy backup` while uploads run, and `canopy restore`: every file acknowledged before the backup
began is in the restored data, byte for byte, and a server on the restored folder serves it."""

from __future__ import annotations

import hashlib
import json
import sqlite3
import threading
import time
from dataclasses import replace
from pathlib import Path

from tests.service.running import Service, capture_files, content_digest, start_service


def _upload_trees(
    service: Service, folder: Path, trees: int, acknowledged: list[tuple[float, int, str, str]]
) -> None:
    """Upload ``trees`` copies of the capture (other tree names), recording each acknowledged file as
    (time acknowledged, capture id, path, sha-256)."""
    manifest = json.loads((folder / "capture.json").read_text())
    files = capture_files(folder)
    with service.client() as client:
        for tree in range(trees):
            created = client.post("/v1/captures", content=json.dumps({**manifest, "tree": f"B-{tree:03d}"}))
            capture_id = created.json()["id"]
            for path, data in files.items():
                sent = client.put(
                    f"/v1/captures/{capture_id}/files/{path}",
                    content=data,
                    headers={"Content-Digest": content_digest(data)},
                )
                assert sent.status_code == 201, sent.text
                acknowledged.append((time.monotonic(), capture_id, path, hashlib.sha256(data).hexdigest()))


def test_a_backup_taken_during_uploads_restores_every_file_acknowledged_before_it(
    tmp_path: Path, tree_capture: Path
) -> None:
    service = start_service(tmp_path / "live")
    acknowledged: list[tuple[float, int, str, str]] = []
    backup_folder = tmp_path / "backup"
    try:
        uploads = threading.Thread(target=_upload_trees, args=(service, tree_capture, 12, acknowledged))
        uploads.start()
        while len(acknowledged) < 20:  # well into the uploads
            time.sleep(0.05)
        began = time.monotonic()
        backed_up = service.canopy("backup", str(backup_folder))
        uploads.join()
    finally:
        service.stop()
    assert backed_up.returncode == 0, backed_up.stderr
    before = [(capture_id, path, digest) for at, capture_id, path, digest in acknowledged if at < began]
    assert 20 <= len(before) < len(acknowledged)  # the backup ran while files were still arriving

    restored_dir = tmp_path / "restored"
    brought_back = service.canopy("restore", str(backup_folder), "--data", str(restored_dir))
    assert brought_back.returncode == 0, brought_back.stderr
    with sqlite3.connect(restored_dir / "canopy.db") as database:
        assert database.execute("PRAGMA integrity_check").fetchone() == ("ok",)
        stored = set(database.execute("SELECT capture_id, path, sha256 FROM capture_files"))
    assert set(before) <= stored
    for _, _, digest in stored:
        blob = restored_dir / "blobs" / digest[:2] / digest
        assert hashlib.sha256(blob.read_bytes()).hexdigest() == digest
    restored = replace(
        service,
        data_dir=restored_dir,
        environment={**service.environment, "CANOPY_DATA_DIR": str(restored_dir)},
    )
    restored.start_server()
    try:
        capture_id = before[0][0]
        with restored.client() as client:  # the live service's keys came back too
            capture = client.get(f"/v1/captures/{capture_id}")
    finally:
        restored.stop()
    assert capture.status_code == 200, capture.text
    assert {path for cid, path, _ in before if cid == capture_id} <= set(capture.json()["files_received"])


def test_restore_refuses_a_data_folder_that_holds_a_database(tmp_path: Path) -> None:
    service = start_service(tmp_path / "live")
    try:
        backed_up = service.canopy("backup", str(tmp_path / "backup"))
        refused = service.canopy("restore", str(tmp_path / "backup"))
    finally:
        service.stop()
    assert backed_up.returncode == 0, backed_up.stderr
    assert refused.returncode == 2
    assert "holds a database already" in refused.stderr


def test_a_second_backup_into_the_same_folder_copies_only_new_files(
    tmp_path: Path, tree_capture: Path
) -> None:
    service = start_service(tmp_path / "live")
    try:
        _upload_trees(service, tree_capture, 1, [])
        first = service.canopy("backup", str(tmp_path / "backup"))
        second = service.canopy("backup", str(tmp_path / "backup"))
    finally:
        service.stop()
    assert first.returncode == 0 and second.returncode == 0, first.stderr + second.stderr
    assert ", 0 copied now," in second.stdout and ", 0 copied now," not in first.stdout
