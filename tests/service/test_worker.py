"""The worker as a process: a kill -9 mid-job loses nothing, crashes are retried three times, failures the
measurement explains fail at once, and a failed capture can be measured again with other settings."""

from __future__ import annotations

import json
import re
import shutil
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.service.postgres import BACKENDS, database_url
from tests.service.running import Service, start_service, upload_capture, wait_for_job


@pytest.fixture(scope="module", params=BACKENDS)
def backend(request: pytest.FixtureRequest) -> str:
    """Every test here runs on SQLite and on PostgreSQL."""
    return str(request.param)


@pytest.fixture
def service(backend: str, tmp_path: Path) -> Iterator[Service]:
    """A fresh `canopy serve` on its own database; start workers with ``service.start_worker()``."""
    with database_url(backend) as url:
        running = start_service(tmp_path, database_url=url, job_lease_s="3")
        yield running
        running.stop()


@pytest.fixture(scope="module")
def working_service(backend: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    """A server with one worker, shared by the tests that need no worker of their own."""
    with database_url(backend) as url:
        running = start_service(tmp_path_factory.mktemp("worker"), database_url=url)
        running.start_worker()
        yield running
        running.stop()


def _wait_until_measuring(service: Service, job_url: str, *, timeout_s: float = 60.0) -> dict[str, object]:
    """Poll until the worker's measurement process has reported a pipeline stage."""
    deadline = time.monotonic() + timeout_s
    with service.client() as client:
        while time.monotonic() < deadline:
            job = client.get(job_url).json()
            if job["state"] == "running" and job["stage"] not in (None, "queued"):
                return dict(job)
            assert job["state"] in ("queued", "running"), job
            time.sleep(0.01)
    raise AssertionError(f"{job_url} never started measuring")


def test_job_of_a_killed_worker_is_finished_by_another_and_stored_once(
    service: Service, tree_capture: Path
) -> None:
    doomed = service.start_worker()
    with service.client() as client:
        capture_id = upload_capture(client, tree_capture)
        job_url = client.post(f"/v1/captures/{capture_id}/jobs").headers["location"]
    running = _wait_until_measuring(service, job_url)
    measuring_pid = _measurement_process(service, worker_index=0)
    doomed.send_signal(signal.SIGKILL)
    doomed.wait()
    _wait_until_gone(measuring_pid)

    service.start_worker()
    with service.client() as client:
        job = wait_for_job(client, job_url)
        jobs = client.get("/v1/jobs", params={"capture_id": capture_id}).json()["items"]
    assert running["attempts"] == 1
    assert job["state"] == "succeeded", job
    assert job["attempts"] == 2
    assert len(jobs) == 1
    assert service.query("SELECT COUNT(*) FROM measurements WHERE job_id = :job", job=job["id"]) == [(1,)]


def test_stopped_worker_hands_its_job_back_without_counting_the_attempt(
    service: Service, tree_capture: Path
) -> None:
    stopping = service.start_worker()
    with service.client() as client:
        capture_id = upload_capture(client, tree_capture)
        job_url = client.post(f"/v1/captures/{capture_id}/jobs").headers["location"]
        _wait_until_measuring(service, job_url)
        stopping.send_signal(signal.SIGTERM)
        assert stopping.wait(timeout=30) == 0
        handed_back = client.get(job_url).json()
        service.start_worker()
        job = wait_for_job(client, job_url)
    assert (handed_back["state"], handed_back["attempts"]) == ("queued", 0)
    assert (job["state"], job["attempts"]) == ("succeeded", 1)


def test_measurement_over_the_time_limit_is_stopped_and_retried_then_fails(
    tmp_path: Path, tree_capture: Path
) -> None:
    service = start_service(tmp_path, job_timeout_s="0.3")
    try:
        service.start_worker()
        with service.client() as client:
            capture_id = upload_capture(client, tree_capture)
            job = wait_for_job(client, client.post(f"/v1/captures/{capture_id}/jobs").headers["location"])
    finally:
        service.stop()
    assert (job["state"], job["attempts"]) == ("failed", 3)
    assert job["error"]["code"] == "measurement_timeout"
    assert "0.3 s" in job["error"]["message"]


def test_crashing_measurement_is_retried_then_stays_failed_after_three_attempts(
    working_service: Service, tree_capture: Path, tmp_path: Path
) -> None:
    service = working_service
    # Its own capture (another tree): the blob removed below must not be shared with other tests.
    capture = _renamed(tree_capture, tmp_path, tree="T-crash")
    with service.client() as client:
        capture_id = upload_capture(client, capture)
        depth = next(record for record in _files(service, capture_id) if record[0] == "views/2/depth.png")
        # Storage lost a blob under the service: every attempt's measurement process dies on it.
        (service.data_dir / "blobs" / depth[1][:2] / depth[1]).unlink()
        job_url = client.post(f"/v1/captures/{capture_id}/jobs").headers["location"]
        job = wait_for_job(client, job_url)
    assert job["state"] == "failed"
    assert job["attempts"] == 3
    assert job["error"]["code"] == "measurement_crashed"
    assert "FileNotFoundError" in job["error"]["message"]
    assert job["measurement_id"] is None


def test_ball_not_found_fails_at_once_naming_view_and_colour_and_a_rerun_succeeds(
    working_service: Service, tree_capture: Path
) -> None:
    with working_service.client() as client:
        capture_id = upload_capture(client, tree_capture)
        strict = client.post(
            f"/v1/captures/{capture_id}/jobs", json={"config": {"balls": {"min_points": 5000}}}
        )
        failed = wait_for_job(client, strict.headers["location"])
        rerun = client.post(f"/v1/captures/{capture_id}/jobs")
        succeeded = wait_for_job(client, rerun.headers["location"])
    assert failed["state"] == "failed"
    assert failed["attempts"] == 1
    assert failed["error"]["code"] == "ball_not_found"
    assert failed["error"]["view"] == "views/1"
    assert failed["error"]["color"] == "red"
    assert rerun.status_code == 202
    assert rerun.json()["id"] != failed["id"]
    assert succeeded["state"] == "succeeded"


def test_repeated_job_request_with_the_same_idempotency_key_returns_the_same_job(
    working_service: Service, tree_capture: Path
) -> None:
    with working_service.client() as client:
        capture_id = upload_capture(client, tree_capture)
        before = client.get("/v1/jobs", params={"capture_id": capture_id}).json()["items"]
        headers = {"Idempotency-Key": "laptop-7f3a"}
        first = client.post(f"/v1/captures/{capture_id}/jobs", headers=headers)
        second = client.post(f"/v1/captures/{capture_id}/jobs", headers=headers)
        after = client.get("/v1/jobs", params={"capture_id": capture_id}).json()["items"]
    assert first.status_code == second.status_code == 202
    assert first.json()["id"] == second.json()["id"]
    assert len(after) == len(before) + 1


def _measurement_process(service: Service, *, worker_index: int) -> int:
    """The pid of the process measuring for a worker, from the worker's log."""
    log = (service.data_dir / f"worker-{worker_index}.log").read_text()
    return int(re.findall(r"measuring in process (\d+)", log)[-1])


def _wait_until_gone(pid: int, *, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while Path(f"/proc/{pid}").exists() and _state(pid) != "Z":
        assert time.monotonic() < deadline, f"measurement process {pid} outlived its killed worker"
        time.sleep(0.05)


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, IndexError):
        return "gone"


def _renamed(capture: Path, into: Path, *, tree: str) -> Path:
    """A copy of ``capture`` labelled as another tree, with a changed depth image (so its own blob)."""
    copy = Path(shutil.copytree(capture, into / tree))
    manifest = json.loads((copy / "capture.json").read_text())
    (copy / "capture.json").write_text(json.dumps({**manifest, "tree": tree}))
    depth = copy / "views" / "2" / "depth.png"
    pixels = np.array(Image.open(depth))
    pixels[0, 0] = pixels[0, 0] + 1
    Image.fromarray(pixels).save(depth)
    return copy


def _files(service: Service, capture_id: int) -> list[tuple[str, str]]:
    return service.query(
        "SELECT path, sha256 FROM capture_files WHERE capture_id = :capture", capture=capture_id
    )
