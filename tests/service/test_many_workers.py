"""Many workers on PostgreSQL, the scale path: four `canopy worker` processes share a queue of 20 jobs; two
are killed with SIGKILL in the middle of a job, and every job still succeeds exactly once, with one
measurement each."""

from __future__ import annotations

import json
import shutil
import signal
import time
from pathlib import Path

from tests.service.postgres import postgres_schema
from tests.service.running import Service, start_service, upload_capture

JOBS = 20
WORKERS = 4


def _queue_row(service: Service, tree_capture: Path, into: Path) -> list[int]:
    """A row of ``JOBS`` trees, each a copy of one capture under its own name, uploaded and queued; the
    jobs' ids."""
    jobs = []
    with service.client() as client:
        for index in range(JOBS):
            folder = Path(shutil.copytree(tree_capture, into / f"T{index:02d}"))
            manifest = json.loads((folder / "capture.json").read_text())
            (folder / "capture.json").write_text(json.dumps({**manifest, "tree": f"T{index:02d}"}))
            capture_id = upload_capture(client, folder)
            started = client.post(f"/v1/captures/{capture_id}/jobs")
            assert started.status_code == 202, started.text
            jobs.append(int(started.json()["id"]))
    return jobs


def _pids_holding_jobs(service: Service) -> set[int]:
    """The worker processes that hold a running job's lease (a lease's owner is host:pid:nonce)."""
    owners = service.query("SELECT lease_owner FROM jobs WHERE state = 'running' AND lease_owner IS NOT NULL")
    return {int(owner.split(":")[1]) for (owner,) in owners}


def _wait(service: Service, condition: str, *, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not service.query(f"SELECT {condition} FROM jobs")[0][0]:
        counts = "SELECT state, COUNT(*) FROM jobs GROUP BY state"
        assert time.monotonic() < deadline, f"jobs never reached {condition}: {service.query(counts)}"
        time.sleep(0.1)


def test_four_workers_two_killed_mid_job_finish_every_job_exactly_once(
    tree_capture: Path, tmp_path: Path
) -> None:
    with postgres_schema() as url:
        # Leases of 10 s: renewed every 3.3 s, they hold on a 2-core machine that four measurements and a
        # parallel test suite keep busy (3 s leases were lost there), and the killed workers' jobs are
        # taken over 10 s after.
        service = start_service(tmp_path, database_url=url, job_lease_s="10")
        try:
            jobs = _queue_row(service, tree_capture, tmp_path / "row")
            workers = [service.start_worker() for _ in range(WORKERS)]
            _wait(service, "COUNT(*) FILTER (WHERE state = 'succeeded') >= 4", timeout_s=300)
            deadline = time.monotonic() + 60
            while len(busy := [w for w in workers if w.pid in _pids_holding_jobs(service)]) < 2:
                assert time.monotonic() < deadline, "fewer than two workers were ever measuring at once"
                time.sleep(0.05)
            killed = busy[:2]
            for worker in killed:
                worker.send_signal(signal.SIGKILL)
                worker.wait()
            _wait(
                service, "COUNT(*) FILTER (WHERE state IN ('succeeded', 'failed')) = COUNT(*)", timeout_s=600
            )
            states = service.query("SELECT id, state, attempts FROM jobs ORDER BY id")
            errors = service.query("SELECT id, error FROM jobs WHERE error IS NOT NULL")
            per_job = dict(service.query("SELECT job_id, COUNT(*) FROM measurements GROUP BY job_id"))
            survivors = [w for w in workers if w not in killed]
        finally:
            service.stop()
    assert [job_id for job_id, _, _ in states] == jobs
    assert [state for _, state, _ in states] == ["succeeded"] * JOBS, (states, errors)
    assert per_job == {job_id: 1 for job_id in jobs}
    # The killed workers' jobs were taken over once their leases ran out: their attempts show it.
    assert sum(attempts for _, _, attempts in states) >= JOBS + 2, states
    assert [worker.returncode for worker in survivors] == [0, 0]  # asked to stop, they ended cleanly
