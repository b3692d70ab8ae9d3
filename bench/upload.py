"""Upload benchmark: throughput of `canopy upload` for a row of captures on loopback, and how long the
client takes to resume once the network is back after a drop.

Starts the real `canopy serve` (no worker: measuring is not what is timed here) on a temporary SQLite file,
simulates ``--count`` two-view captures, and runs the real `canopy upload` on the row:
1. straight to the server: wall time and MB/s (the process's whole run: start, checks, requests);
2. ``--outages`` times, as a new orchard, through a proxy that goes down for ``--outage-s`` seconds after a
   quarter of the requests (open connections reset, new ones refused): the resume delay is the time from
   the network's return to the next request reaching the server (the client sleeps in its backoff).

    .venv/bin/python bench/upload.py [--count 20] [--seed 11] [--outage-s 5] [--outages 5]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the test harness starts the processes

from canopy_core.simulate import simulate_captures
from service.client.receipts import RECEIPT_NAME
from tests.service.flaky_proxy import Faults, FlakyProxy
from tests.service.running import CANOPY, Service, capture_files, start_service


def _upload(service: Service, server: str, row: Path) -> float:
    started = time.perf_counter()
    subprocess.run(
        [CANOPY, "upload", str(row), "--server", server, "--key", service.admin_key],
        env=service.environment,
        check=True,
        capture_output=True,
    )
    return time.perf_counter() - started


def _relabel(row: Path, orchard: str) -> None:
    """Make the row's captures new to the server: another orchard, no receipts."""
    for manifest in row.glob("*/capture.json"):
        document = json.loads(manifest.read_text())
        manifest.write_text(json.dumps({**document, "orchard": orchard}))
    for receipt in row.glob(f"*/{RECEIPT_NAME}"):
        receipt.unlink()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=20)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--outage-s", type=float, default=5.0)
    parser.add_argument("--outages", type=int, default=5, help="outage runs, for the median resume delay")
    options = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="canopy-upload-bench-") as scratch:
        row = Path(scratch) / "row"
        simulate_captures(row, seed=options.seed, count=options.count)
        files = [data for capture in row.iterdir() for data in capture_files(capture).values()]
        size_bytes = sum(len(data) for data in files)
        service = start_service(Path(scratch))
        try:
            elapsed_s = _upload(service, service.url, row)
            print(
                f"{options.count} captures, {size_bytes / 1e6:.1f} MB, {len(files)} files: "
                f"{elapsed_s:.2f} s, {size_bytes / 1e6 / elapsed_s:.1f} MB/s (whole `canopy upload` run)"
            )
            requests = options.count * 9
            delays_s = []
            for outage in range(options.outages):
                _relabel(row, f"Outage {outage}")
                proxy = FlakyProxy(
                    int(service.url.rsplit(":", 1)[1]),
                    Faults(refuse_after_requests=requests // 4, refuse_s=options.outage_s, seed=outage),
                )
                try:
                    elapsed_s = _upload(service, proxy.url, row)
                finally:
                    proxy.close()
                [(_start, back)] = proxy.refusals
                delays_s.append(min(moment for moment in proxy.reached_at if moment > back) - back)
                print(
                    f"outage {outage + 1}: {options.outage_s:g} s after {requests // 4} requests, "
                    f"{proxy.refused} connection(s) refused; upload {elapsed_s:.2f} s in all; "
                    f"first request {delays_s[-1]:.2f} s after the network came back"
                )
            print(f"resume after the network is back: median {statistics.median(delays_s):.2f} s")
        finally:
            service.stop()


if __name__ == "__main__":
    main()
