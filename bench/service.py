"""Service benchmark: job time of a two-view capture from upload finished to job succeeded, and the latency
of ``GET /v1/jobs/{id}`` while the worker is busy.

Starts the real `canopy serve` and one `canopy worker` on a temporary SQLite file, uploads ``--count``
simulated captures one after another over HTTP, starts each one's job and polls it every ``--poll-ms``
(a busy dashboard) until it succeeds. Prints each job's time and the medians.

    .venv/bin/python bench/service.py [--count 5] [--seed 7] [--poll-ms 50]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the test harness starts the processes

from canopy_core.simulate import simulate_captures
from tests.service.running import start_service, upload_capture


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=5)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--poll-ms", type=float, default=50.0)
    options = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="canopy-service-bench-") as scratch:
        captures = simulate_captures(Path(scratch) / "captures", seed=options.seed, count=options.count)
        service = start_service(Path(scratch))
        try:
            service.start_worker()
            job_times_s: list[float] = []
            latencies_s: list[float] = []
            with service.client() as client:
                for capture in captures:
                    capture_id = upload_capture(client, capture)
                    uploaded = time.perf_counter()
                    job_url = client.post(f"/v1/captures/{capture_id}/jobs").headers["location"]
                    while True:
                        asked = time.perf_counter()
                        job = client.get(job_url).json()
                        answered = time.perf_counter()
                        if job["state"] in ("succeeded", "failed"):
                            break
                        if job["state"] == "running":
                            latencies_s.append(answered - asked)
                        time.sleep(options.poll_ms / 1000)
                    job_times_s.append(answered - uploaded)
                    print(
                        f"{capture.name}: {job['state']:<9} job {job_times_s[-1]:.2f} s "
                        f"(upload finished to {job['state']}){'' if job['error'] is None else job['error']}"
                    )
        finally:
            service.stop()
    print(f"median job time:           {statistics.median(job_times_s):.2f} s over {len(job_times_s)} jobs")
    latencies_ms = sorted(1000 * value for value in latencies_s)
    print(
        f"GET /v1/jobs/{{id}} latency while running: median {statistics.median(latencies_ms):.1f} ms, "
        f"p95 {latencies_ms[int(0.95 * (len(latencies_ms) - 1))]:.1f} ms, max {latencies_ms[-1]:.1f} ms "
        f"over {len(latencies_ms)} requests"
    )


if __name__ == "__main__":
    main()
