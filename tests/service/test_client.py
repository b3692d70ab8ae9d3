"""The capture client (`canopy upload`) against the real server, through a link that fails like orchard
Wi-Fi: every capture arrives once, whole, and is measured; a killed upload resumes without re-sending."""

from __future__ import annotations

import hashlib
import json
import shutil
import signal
import sqlite3
import subprocess
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

from service.client.receipts import Receipt, ServerReceipt
from service.client.upload import files_to_send as files_of
from service.client.upload import fingerprint, receipt_complete
from tests.service.flaky_proxy import Faults, FlakyProxy
from tests.service.running import CANOPY, Service, capture_files

TREES = ("T-a", "T-b", "T-c", "T-d")


def _row(tree_capture: Path, into: Path, trees: tuple[str, ...]) -> Path:
    """A row folder of captures of ``trees``: copies of one simulated capture, each labelled as its tree."""
    row = into / "row"
    for tree in trees:
        folder = Path(shutil.copytree(tree_capture, row / tree))
        manifest = json.loads((folder / "capture.json").read_text())
        (folder / "capture.json").write_text(json.dumps({**manifest, "tree": tree}))
    return row


def _upload(service: Service, server: str, row: Path, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [CANOPY, "upload", str(row), "--server", server, "--key", service.admin_key, *extra],
        env=service.environment,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _server_port(service: Service) -> int:
    return int(service.url.rsplit(":", 1)[1])


def _stored(service: Service) -> dict[str, dict[str, str]]:
    """Per tree, the files the server recorded (path -> SHA-256); fails if a tree has two captures."""
    with sqlite3.connect(service.data_dir / "canopy.db") as database:
        captures = database.execute(
            "SELECT trees.name, captures.id FROM captures JOIN trees ON trees.id = captures.tree_id"
        ).fetchall()
        files = database.execute("SELECT capture_id, path, sha256 FROM capture_files").fetchall()
    trees = [tree for tree, _ in captures]
    assert len(trees) == len(set(trees)), f"a tree has two captures: {trees}"
    by_capture = {capture_id: tree for tree, capture_id in captures}
    stored: dict[str, dict[str, str]] = {tree: {} for tree in trees}
    for capture_id, path, sha256 in files:
        stored[by_capture[capture_id]][path] = sha256
    return stored


def _local(row: Path, tree: str) -> dict[str, str]:
    return {path: hashlib.sha256(data).hexdigest() for path, data in capture_files(row / tree).items()}


def _jobs(service: Service) -> list[tuple[str, str]]:
    with sqlite3.connect(service.data_dir / "canopy.db") as database:
        return database.execute(
            "SELECT trees.name, jobs.state FROM jobs JOIN captures ON captures.id = jobs.capture_id "
            "JOIN trees ON trees.id = captures.tree_id ORDER BY trees.name"
        ).fetchall()


def test_upload_over_a_failing_link_stores_every_capture_once_whole_and_measured(
    service: Service, tree_capture: Path, tmp_path: Path
) -> None:
    service.start_worker()
    row = _row(tree_capture, tmp_path, TREES)
    proxy = FlakyProxy(
        _server_port(service),
        Faults(cut_body=0.2, lose_response=0.15, refuse_after_requests=12, refuse_s=2.0, seed=5),
    )
    try:
        client = _upload(service, proxy.url, row, "--wait", "--retry-for", "120")
        stdout, stderr = client.communicate(timeout=600)
    finally:
        proxy.close()
    assert client.returncode == 0, stderr
    assert (proxy.cut, proxy.lost, proxy.refused) > (0, 0, 0) and min(
        proxy.cut, proxy.lost, proxy.refused
    ) > 0
    stored = _stored(service)
    assert sorted(stored) == sorted(TREES)
    for tree in TREES:
        assert stored[tree] == _local(row, tree), tree
    assert _jobs(service) == [(tree, "succeeded") for tree in TREES]
    for tree in TREES:
        assert tree in stdout


def test_killed_upload_resumes_without_resending_acknowledged_files(
    service: Service, tree_capture: Path, tmp_path: Path
) -> None:
    row = _row(tree_capture, tmp_path, TREES[:3])
    slow = FlakyProxy(_server_port(service), Faults(bytes_per_s=2_000_000))
    try:
        first = _upload(service, slow.url, row)
        deadline = time.monotonic() + 120
        while sum(len(files) for files in _stored(service).values()) < 4:
            assert first.poll() is None, "the upload finished before it could be killed"
            assert time.monotonic() < deadline
            time.sleep(0.02)
        first.send_signal(signal.SIGKILL)
        first.wait()
        acknowledged_before = {tree: set(files) for tree, files in _stored(service).items()}
    finally:
        slow.close()
    fast = FlakyProxy(_server_port(service))
    try:
        second = _upload(service, fast.url, row)
        _, stderr = second.communicate(timeout=300)
        resent = fast.puts()
    finally:
        fast.close()
    assert second.returncode == 0, stderr
    assert 4 <= sum(len(files) for files in acknowledged_before.values()) < 18
    stored = _stored(service)
    with sqlite3.connect(service.data_dir / "canopy.db") as database:
        capture_of = dict(
            database.execute("SELECT trees.name, captures.id FROM captures JOIN trees ON trees.id = tree_id")
        )
    for tree, files in acknowledged_before.items():
        for path in files:
            assert resent[f"/v1/captures/{capture_of[tree]}/files/{path}"] == 0, (tree, path)
    # A file in flight at the kill may be committed after it, and then not sent again either.
    assert sum(resent.values()) <= 18 - sum(len(files) for files in acknowledged_before.values())
    for tree in TREES[:3]:
        assert stored[tree] == _local(row, tree)
    assert [tree for tree, _state in _jobs(service)] == list(TREES[:3])


def test_second_upload_of_a_finished_row_only_checks_the_server_still_has_it(
    service: Service, tree_capture: Path, tmp_path: Path
) -> None:
    row = _row(tree_capture, tmp_path, TREES[:2])
    proxy = FlakyProxy(_server_port(service))
    try:
        assert _upload(service, proxy.url, row).wait(timeout=300) == 0
        first = Counter(proxy.reached_server)
        assert _upload(service, proxy.url, row).wait(timeout=300) == 0
        second = Counter(proxy.reached_server) - first
    finally:
        proxy.close()
    identify = ("GET", "/v1/keys/current")  # once per run, before anything is sent
    assert first[identify] == 1 and sum(first.values()) == 1 + 2 * 9
    assert sorted(second.elements()) == [("GET", f"/v1/captures/{n}") for n in (1, 2)] + [identify]


def test_capture_changed_after_its_upload_is_reported_not_skipped(
    service: Service, tree_capture: Path, tmp_path: Path
) -> None:
    row = _row(tree_capture, tmp_path, TREES[:1])
    assert _upload(service, service.url, row).wait(timeout=300) == 0
    manifest = json.loads((row / "T-a" / "capture.json").read_text())
    (row / "T-a" / "capture.json").write_text(json.dumps({**manifest, "sensor": "kinect-v2 (re-labelled)"}))
    again = _upload(service, service.url, row)
    _, stderr = again.communicate(timeout=300)
    assert again.returncode == 1
    assert "T-a" in stderr and "HTTP 409" in stderr and "different capture.json" in stderr


def test_a_file_reshot_after_its_upload_is_a_conflict_not_already_there(
    service: Service, tree_capture: Path, tmp_path: Path
) -> None:
    """The receipt and the server both name views/1/depth.png, but the folder's bytes are new: skipping it
    would report done a capture the server holds other bytes of (and measures the old depth)."""
    row = _row(tree_capture, tmp_path, TREES[:1])
    assert _upload(service, service.url, row).wait(timeout=300) == 0
    depth = row / "T-a" / "views" / "1" / "depth.png"
    depth.write_bytes(depth.read_bytes() + b"re-shot")  # trailing bytes after IEND: still a valid PNG
    again = _upload(service, service.url, row)
    _, stderr = again.communicate(timeout=300)
    assert again.returncode == 1
    assert "views/1/depth.png: changed since it was sent to capture 1" in stderr
    assert "DELETE /v1/captures/1" in stderr
    assert _stored(service)["T-a"]["views/1/depth.png"] != hashlib.sha256(depth.read_bytes()).hexdigest()


def test_server_that_lost_a_capture_gets_it_again(
    service: Service, tree_capture: Path, tmp_path: Path
) -> None:
    row = _row(tree_capture, tmp_path, TREES[:1])
    assert _upload(service, service.url, row).wait(timeout=300) == 0
    with sqlite3.connect(service.data_dir / "canopy.db") as database:  # as a restore from an old backup
        database.execute("PRAGMA foreign_keys=ON")
        database.execute("DELETE FROM orchards")
    assert _stored(service) == {}
    assert _upload(service, service.url, row).wait(timeout=300) == 0
    assert _stored(service) == {"T-a": _local(row, "T-a")}


def test_receipt_naming_an_id_the_server_gave_another_capture_does_not_skip_this_one(
    service: Service, tree_capture: Path, tmp_path: Path
) -> None:
    row = _row(tree_capture, tmp_path, TREES[:2])
    assert _upload(service, service.url, row / "T-a").wait(timeout=300) == 0
    # As after a server reset: T-b's receipt says "done" under the id that T-a holds on this server.
    files = files_of(row / "T-b")
    done = ServerReceipt(capture_id=1, job_id=1, fingerprint=fingerprint(row / "T-b", files))
    Receipt(servers={service.url: done}).save(row / "T-b")
    assert _upload(service, service.url, row / "T-b").wait(timeout=300) == 0
    assert _stored(service) == {tree: _local(row, tree) for tree in TREES[:2]}


def test_watch_sends_captures_as_they_appear_and_once_the_network_is_back(
    service: Service, tree_capture: Path, tmp_path: Path
) -> None:
    row = _row(tree_capture, tmp_path, TREES[:2])
    day = tmp_path / "today"
    day.mkdir()
    proxy = FlakyProxy(_server_port(service))
    proxy.refuse_next(3)  # the laptop starts out of range: its first three tries are refused
    watcher = subprocess.Popen(
        [CANOPY, "watch", str(day), "--server", proxy.url, "--key", service.admin_key]
        + ["--interval", "0.2", "--settle", "0.5"],
        env=service.environment,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        shutil.copytree(row / "T-a", day / "T-a")
        _wait_for(lambda: sorted(_stored(service)) == ["T-a"] and len(_stored(service)["T-a"]) == 6)
        shutil.copytree(row / "T-b", day / "T-b")
        _wait_for(lambda: sorted(_stored(service)) == ["T-a", "T-b"] and len(_stored(service)["T-b"]) == 6)
        _wait_for(lambda: all(receipt_complete(day / tree, proxy.url) for tree in ("T-a", "T-b")))
    finally:
        watcher.send_signal(signal.SIGINT)
        output, _ = watcher.communicate(timeout=60)
        proxy.close()
    assert proxy.refused == 3
    assert [tree for tree, _ in _jobs(service)] == ["T-a", "T-b"]
    for tree in ("T-a", "T-b"):
        assert _stored(service)[tree] == _local(row, tree)
    assert "T-a" in output


def _wait_for(condition: Callable[[], bool], *, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "the condition never held"
        time.sleep(0.1)
