"""Load benchmark: many uploaders and pollers against `canopy serve` while two workers measure.

Starts the real `canopy serve` on a temporary SQLite file and two `canopy worker` processes, simulates a
few two-view captures and has ``--uploaders`` threads, each with its own capture key (a crew of laptops),
send ``--captures`` captures each (create, six file PUTs, start the job), as `canopy upload` does:
honouring Retry-After on 429 and 503. Meanwhile ``--pollers`` threads with a read key follow jobs as a
dashboard would (GET /v1/jobs/{id} with If-None-Match, GET /v1/jobs). Then it waits for every job and
prints, per route, while the uploads run and after (only pollers and the measuring workers), the count
and p50 / p95 / p99 / max latency; the status counts; the jobs lost (not
succeeded) and duplicated (more than one measurement); and the API's peak resident memory. Everything
runs on this one machine, the clients too: their own CPU use is part of what the latencies show.

    .venv/bin/python bench/load.py [--uploaders 50] [--captures 1] [--pollers 10]
"""

from __future__ import annotations

import argparse
import json
import random
import sqlite3
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the test harness starts the processes

from canopy_core.simulate import simulate_capture
from tests.service.running import Service, capture_files, content_digest, start_service

_RETRIED = {429, 503}


class Recorder:
    """Latencies by route and status counts, from every client thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.phase = "uploading"
        """``uploading`` while uploads run, then ``measuring`` (pollers and workers only)."""
        self.latencies_s: dict[tuple[str, str], list[float]] = defaultdict(list)
        self.statuses: Counter[tuple[str, int]] = Counter()

    def call(
        self, client: httpx.Client, route: str, method: str, url: str, **kwargs: object
    ) -> httpx.Response:
        """Send a request, record it under ``route``, and send it again after Retry-After on 429 / 503."""
        while True:
            started = time.perf_counter()
            response = client.request(method, url, **kwargs)  # type: ignore[arg-type]
            elapsed = time.perf_counter() - started
            with self._lock:
                self.latencies_s[(self.phase, route)].append(elapsed)
                self.statuses[(route, response.status_code)] += 1
            if response.status_code not in _RETRIED:
                return response
            time.sleep(float(response.headers.get("retry-after", "1")))


def _manifest(template: dict, uploader: int, number: int) -> bytes:
    return json.dumps({**template, "row": f"R{uploader:02d}", "tree": f"T{number:03d}"}).encode()


def _upload(
    service: Service, recorder: Recorder, key: str, uploader: int, captures: list[Path], count: int
) -> list[str]:
    """One laptop's uploads; the job URLs it started."""
    jobs = []
    with service.client(key) as client:
        for number in range(count):
            folder = captures[(uploader + number) % len(captures)]
            template = json.loads((folder / "capture.json").read_text())
            created = recorder.call(
                client,
                "POST /v1/captures",
                "POST",
                "/v1/captures",
                content=_manifest(template, uploader, number),
            )
            capture_id = created.json()["id"]
            for path, data in capture_files(folder).items():
                recorder.call(
                    client,
                    "PUT /v1/captures/{id}/files/{path}",
                    "PUT",
                    f"/v1/captures/{capture_id}/files/{path}",
                    content=data,
                    headers={"Content-Digest": content_digest(data)},
                )
            started = recorder.call(
                client, "POST /v1/captures/{id}/jobs", "POST", f"/v1/captures/{capture_id}/jobs"
            )
            jobs.append(started.headers["location"])
    return jobs


def _poll(service: Service, recorder: Recorder, key: str, jobs: list[str], done: threading.Event) -> None:
    """A dashboard: follow a random started job with its ETag, and list the newest jobs now and then."""
    etags: dict[str, str] = {}
    chance = random.Random(threading.get_ident())
    with service.client(key) as client:
        while not done.is_set():
            if jobs and chance.random() < 0.8:
                url = chance.choice(jobs)
                headers = {"If-None-Match": etags[url]} if url in etags else {}
                answer = recorder.call(client, "GET /v1/jobs/{id}", "GET", url, headers=headers)
                if "etag" in answer.headers:
                    etags[url] = answer.headers["etag"]
            else:
                recorder.call(client, "GET /v1/jobs", "GET", "/v1/jobs", params={"limit": 20})
            time.sleep(0.2)


def _memory_peak_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _outcome(service: Service) -> tuple[int, int, int]:
    """Jobs, those not succeeded, those with more than one measurement."""
    with sqlite3.connect(service.data_dir / "canopy.db") as database:
        jobs = database.execute("SELECT COUNT(*) FROM jobs").fetchone()[0]
        lost = database.execute("SELECT COUNT(*) FROM jobs WHERE state != 'succeeded'").fetchone()[0]
        duplicated = database.execute(
            "SELECT COUNT(*) FROM (SELECT job_id FROM measurements GROUP BY job_id HAVING COUNT(*) > 1)"
        ).fetchone()[0]
    return jobs, lost, duplicated


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--uploaders", type=int, default=50)
    parser.add_argument("--captures", type=int, default=1, help="captures each uploader sends")
    parser.add_argument("--pollers", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=31)
    options = parser.parse_args()
    recorder = Recorder()
    with tempfile.TemporaryDirectory(prefix="canopy-load-bench-") as scratch:
        captures = [
            simulate_capture(Path(scratch) / f"capture_{i}", seed=options.seed * 100 + i, n_views=2)
            for i in range(3)
        ]
        service = start_service(Path(scratch) / "service")
        try:
            for _ in range(options.workers):
                service.start_worker()
            keys = [service.create_key("capture") for _ in range(options.uploaders)]
            read_key = service.create_key("read")
            started_jobs: list[str] = []
            done = threading.Event()
            pollers = [
                threading.Thread(target=_poll, args=(service, recorder, read_key, started_jobs, done))
                for _ in range(options.pollers)
            ]
            for poller in pollers:
                poller.start()
            started = time.perf_counter()
            with ThreadPoolExecutor(options.uploaders) as pool:
                futures = [
                    pool.submit(_upload, service, recorder, key, index, captures, options.captures)
                    for index, key in enumerate(keys)
                ]
                for future in futures:
                    started_jobs.extend(future.result())
            uploaded_s = time.perf_counter() - started
            recorder.phase = "measuring"
            with service.client(read_key) as client:
                deadline = time.monotonic() + 1800
                while time.monotonic() < deadline:
                    pending = client.get("/v1/jobs", params={"state": ["queued", "running"], "limit": 1})
                    if not pending.json()["items"]:
                        break
                    time.sleep(1.0)
            measured_s = time.perf_counter() - started
            done.set()
            for poller in pollers:
                poller.join()
            peak_mib = _memory_peak_mib(service.server.pid)
            jobs, lost, duplicated = _outcome(service)
        finally:
            service.stop()
    print(
        f"{options.uploaders} uploaders x {options.captures} captures, {options.pollers} pollers, "
        f"{options.workers} workers: uploads done in {uploaded_s:.1f} s, every job finished in "
        f"{measured_s:.1f} s"
    )
    print(f"  {'while':<11}{'route':<38}{'count':>7}{'p50 ms':>9}{'p95 ms':>9}{'p99 ms':>9}{'max ms':>9}")
    for (phase, route), latencies in sorted(
        recorder.latencies_s.items(), key=lambda item: item[0][0] != "uploading"
    ):
        ms = np.array(latencies) * 1000
        p50, p95, p99 = np.percentile(ms, [50, 95, 99])
        print(f"  {phase:<11}{route:<38}{ms.size:>7}{p50:>9.0f}{p95:>9.0f}{p99:>9.0f}{ms.max():>9.0f}")
    print(
        "  statuses: "
        + ", ".join(f"{route} {status}: {n}" for (route, status), n in sorted(recorder.statuses.items()))
    )
    print(
        f"  jobs: {jobs}, lost (not succeeded): {lost}, duplicated (more than one measurement): {duplicated}"
    )
    print(f"  API peak resident memory: {peak_mib:.0f} MiB")


if __name__ == "__main__":
    main()
