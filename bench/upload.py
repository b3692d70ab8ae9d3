"""Upload benchmark: throughput of `canopy upload` for a row of captures on loopback, and how long the
client takes to resume once the network is back after a drop.

Starts the real `canopy serve` (no worker: measuring is not what is timed here) on a temporary SQLite file,
simulates ``--count`` two-view captures, and runs the real `canopy upload` on the row:
1. straight to the server: wall time and MB/s (the process's whole run: start, checks, requests);
2. through a proxy that refuses every connection for ``--outage-s`` seconds after a quarter of the
   requests: the resume delay is the time from the network's return to the next request reaching the
   server (the client is then sleeping in its backoff).

    .venv/bin/python bench/upload.py [--count 20] [--seed 11] [--outage-s 5]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the test harness starts the processes

from canopy_core.simulate import simulate_captures
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=20)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--outage-s", type=float, default=5.0)
    options = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="canopy-upload-bench-") as scratch:
        rows = [Path(scratch) / name for name in ("direct", "outage")]
        for row in rows:
            simulate_captures(row, seed=options.seed, count=options.count)
        size_bytes = sum(
            len(data) for capture in rows[0].iterdir() for data in capture_files(capture).values()
        )
        for index, row in enumerate(rows):  # a second orchard for the outage run: nothing there yet
            for manifest in row.glob("*/capture.json"):
                manifest.write_text(manifest.read_text().replace("Simulated block", f"Block {index}"))
        service = start_service(Path(scratch))
        try:
            elapsed_s = _upload(service, service.url, rows[0])
            print(
                f"{options.count} captures, {size_bytes / 1e6:.1f} MB, {6 * options.count} files: "
                f"{elapsed_s:.2f} s, {size_bytes / 1e6 / elapsed_s:.1f} MB/s (whole `canopy upload` run)"
            )
            requests = options.count * 9
            proxy = FlakyProxy(
                int(service.url.rsplit(":", 1)[1]),
                Faults(refuse_after_requests=requests // 4, refuse_s=options.outage_s),
            )
            try:
                elapsed_s = _upload(service, proxy.url, rows[1])
            finally:
                proxy.close()
            [(_start, back)] = proxy.refusals
            resumed = min(moment for moment in proxy.reached_at if moment > back)
            print(
                f"with a {options.outage_s:g} s outage after {requests // 4} requests: "
                f"{elapsed_s:.2f} s in all; {proxy.refused} connection(s) refused; "
                f"first request after the network came back: {resumed - back:.2f} s later"
            )
        finally:
            service.stop()


if __name__ == "__main__":
    main()
