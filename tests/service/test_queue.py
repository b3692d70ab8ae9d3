"""The job queue on both databases: SQLite (the embedded default) and PostgreSQL (the scale path).

Claims are exclusive under concurrency, leases expire into retries, and a worker that lost its lease can
neither renew nor finish the job.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import select

from service.captures.service import create_capture
from service.database import Database
from service.jobs.queue import Lease, claim, complete, fail, release, renew
from service.jobs.service import create_job
from service.keys.service import create_key
from service.migrate import upgrade
from service.models import Capture, CaptureFile, Job, Measurement
from tests.service.postgres import BACKENDS, database_url

MANIFEST = {
    "format": "canopy-capture/1",
    "orchard": "North block",
    "row": "R12",
    "tree": "T07",
    "captured_at": "2026-11-20T08:31:00Z",
    "views": ["views/1", "views/2"],
}


@pytest.fixture(params=BACKENDS)
def database(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Database]:
    """A migrated, empty database: a SQLite file, or a schema of its own in the test PostgreSQL."""
    with database_url(request.param) as url:
        database = Database(url or f"sqlite:///{tmp_path / 'queue.db'}")
        try:
            upgrade(database)
            yield database
        finally:
            database.dispose()


def _queue_jobs(database: Database, count: int) -> list[int]:
    with database.writing() as session:
        key = create_key(session, name="queue tests", scopes=["capture"]).record
        capture, _ = create_capture(session, json.dumps(MANIFEST).encode(), key=key)
        jobs = [Job(capture_id=capture.id) for _ in range(count)]
        session.add_all(jobs)
        session.flush()
        return [job.id for job in jobs]


def _claim(database: Database, owner: str, *, lease_s: float = 30.0, max_attempts: int = 3) -> Lease | None:
    with database.writing() as session:
        return claim(session, owner=owner, lease_s=lease_s, max_attempts=max_attempts)


def test_claims_take_the_oldest_job_first_and_never_the_same_twice(database: Database) -> None:
    first_id, second_id = _queue_jobs(database, 2)
    first, second = _claim(database, "a"), _claim(database, "b")
    assert (first.job_id, second.job_id) == (first_id, second_id)
    assert _claim(database, "c") is None


def test_concurrent_workers_claim_each_job_exactly_once(database: Database) -> None:
    job_ids = _queue_jobs(database, 24)
    claimed: list[int] = []
    lock = threading.Lock()

    def drain(owner: str) -> None:
        while (lease := _claim(database, owner)) is not None:
            with lock:
                claimed.append(lease.job_id)

    threads = [threading.Thread(target=drain, args=(f"worker-{n}",)) for n in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(claimed) == job_ids


def test_expired_lease_moves_the_job_to_another_worker_and_fences_the_first(database: Database) -> None:
    _queue_jobs(database, 1)
    lost = _claim(database, "killed", lease_s=0.2)
    time.sleep(0.3)
    taken = _claim(database, "rescuer")
    assert taken is not None and taken.job_id == lost.job_id
    assert taken.attempt == 2
    with database.writing() as session:
        assert not renew(session, lost, lease_s=30.0)
        assert complete(session, lost, result={}, cloud_sha256="0" * 64, cloud_points=0) is None
    result = {"height_m": 2.0, "width_m": 1.5, "thickness_m": 1.2}
    with database.writing() as session:
        assert complete(session, taken, result=result, cloud_sha256="0" * 64, cloud_points=10) is not None
    with database.reading() as session:
        job = session.get_one(Job, taken.job_id)
        stored = list(session.scalars(select(Measurement).where(Measurement.job_id == job.id)))
    assert (job.state, job.attempts, len(stored)) == ("succeeded", 2, 1)


def test_job_whose_workers_keep_dying_fails_after_the_last_attempt(database: Database) -> None:
    [job_id] = _queue_jobs(database, 1)
    for _ in range(2):
        assert _claim(database, "dies", lease_s=0.1, max_attempts=2) is not None
        time.sleep(0.15)
    assert _claim(database, "next", max_attempts=2) is None
    with database.reading() as session:
        job = session.get_one(Job, job_id)
    assert job.state == "failed"
    assert job.error is not None and job.error["code"] == "worker_lost"


def test_retried_failure_requeues_until_attempts_run_out(database: Database) -> None:
    [job_id] = _queue_jobs(database, 1)
    error = {"code": "measurement_crashed", "message": "boom"}
    states = []
    for attempt in range(3):
        lease = _claim(database, "w")
        assert lease is not None and lease.attempt == attempt + 1
        with database.writing() as session:
            assert fail(session, lease, error=error, retry=True, max_attempts=3)
        with database.reading() as session:
            states.append(session.get_one(Job, job_id).state)
    assert states == ["queued", "queued", "failed"]


def test_released_job_is_claimed_again_without_counting_the_attempt(database: Database) -> None:
    _queue_jobs(database, 1)
    lease = _claim(database, "stopping")
    with database.writing() as session:
        assert release(session, lease)
    again = _claim(database, "other")
    assert again is not None and again.attempt == 1


def test_requests_for_the_same_capture_at_once_without_an_idempotency_key_queue_one_job(
    database: Database,
) -> None:
    with database.writing() as session:
        key = create_key(session, name="queue tests", scopes=["capture"]).record
        capture, _ = create_capture(session, json.dumps(MANIFEST).encode(), key=key)
        for view in MANIFEST["views"]:
            for name in ("camera.json", "depth.png", "color.png"):
                session.add(
                    CaptureFile(capture_id=capture.id, path=f"{view}/{name}", sha256="0" * 64, size_bytes=1)
                )
    start = threading.Barrier(8)
    created: list[bool] = []

    def request() -> None:
        start.wait()
        with database.writing() as session:
            mine = session.get_one(Capture, capture.id)
            created.append(create_job(session, mine, overrides=None, idempotency_key=None)[1])

    threads = [threading.Thread(target=request) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    with database.reading() as session:
        jobs = list(session.scalars(select(Job).where(Job.capture_id == capture.id)))
    assert len(jobs) == 1
    assert sorted(created) == [False] * 7 + [True]
