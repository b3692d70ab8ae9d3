"""Scaling benchmark: jobs per minute with 1, 2 and 4 workers sharing one PostgreSQL queue.

For each worker count, starts the real `canopy serve` on a fresh PostgreSQL schema (the server
``CANOPY_TEST_POSTGRES_URL`` names, default the local one) and queues ``--jobs`` measurement jobs of
simulated two-view captures (all uploaded before any worker starts), then starts the workers and times
from their start until the last job succeeds. Prints jobs per minute and the speed-up over one worker.

    .venv/bin/python bench/scale.py [--jobs 16] [--workers 1 2 4] [--seed 7]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the test harness starts the processes

import boto3

from canopy_core.simulate import simulate_captures
from tests.service.postgres import postgres_schema
from tests.service.running import Service, start_service, upload_capture
from tests.service.s3 import CREDENTIALS, s3_server


def _queue(service: Service, captures: list[Path], jobs: int, scratch: Path) -> None:
    """Upload ``jobs`` captures (the simulated ones in turn, each as a tree of its own), a job for each."""
    with service.client() as client:
        for index in range(jobs):
            folder = Path(shutil.copytree(captures[index % len(captures)], scratch / f"T{index:03d}"))
            manifest = json.loads((folder / "capture.json").read_text())
            (folder / "capture.json").write_text(json.dumps({**manifest, "tree": f"T{index:03d}"}))
            capture_id = upload_capture(client, folder)
            assert client.post(f"/v1/captures/{capture_id}/jobs").status_code == 202


def _run(workers: int, captures: list[Path], jobs: int, scratch: Path, s3: dict[str, str]) -> float:
    """Jobs per minute with ``workers`` workers on a queue of ``jobs``; ``s3``: the object store's settings
    (none: the blob folder)."""
    with postgres_schema() as url:
        service = start_service(scratch, database_url=url, **s3)
        try:
            _queue(service, captures, jobs, scratch / "row")
            started = time.perf_counter()
            for _ in range(workers):
                service.start_worker()
            while True:
                [(finished, failed)] = service.query(
                    "SELECT COUNT(*) FILTER (WHERE state IN ('succeeded', 'failed')), "
                    "COUNT(*) FILTER (WHERE state = 'failed') FROM jobs"
                )
                if finished == jobs:
                    break
                time.sleep(0.2)
            elapsed = time.perf_counter() - started
        finally:
            service.stop()
    if failed:
        print(f"  ({failed} of {jobs} jobs failed)")
    return 60.0 * jobs / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=16)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--object-store", action="store_true", help="blobs in a bucket of moto's S3 server")
    options = parser.parse_args()
    where = "an S3 bucket (moto)" if options.object_store else "the blob folder"
    print(
        f"{os.cpu_count()} CPUs; {options.jobs} two-view jobs per run (worker start included); "
        f"blobs in {where}"
    )
    with (
        tempfile.TemporaryDirectory(prefix="canopy-scale-bench-") as scratch,
        _object_store(options.object_store) as endpoint,
    ):
        captures = simulate_captures(Path(scratch) / "captures", seed=options.seed, count=4)
        baseline = None
        for workers in options.workers:
            s3 = {}
            if endpoint is not None:
                bucket = f"canopy-scale-{workers}"
                boto3.client("s3", endpoint_url=endpoint).create_bucket(Bucket=bucket)
                s3 = {"s3_bucket": bucket, "s3_endpoint_url": endpoint}
            rate = _run(workers, captures, options.jobs, Path(scratch) / f"run-{workers}", s3)
            baseline = baseline or rate
            print(f"{workers} worker(s): {rate:5.1f} jobs/min  (x{rate / baseline:.2f} of the first)")


@contextmanager
def _object_store(wanted: bool) -> Iterator[str | None]:
    """The URL of moto's S3 server, started for the benchmark (credentials set for every process), or None."""
    if not wanted:
        yield None
        return
    os.environ.update(CREDENTIALS)
    with s3_server() as url:
        yield url


if __name__ == "__main__":
    main()
