"""Memory benchmark: the API's peak resident memory while large uploads arrive at once.

Starts the real `canopy serve` on a temporary SQLite file, makes one colour PNG of about ``--mb`` MB
(random pixels, so it does not compress; within the 40 Mpx image limit) and sends it ``--uploads`` times
at once, each from its own capture-scope key (a field crew of laptops), to the views of one capture.
Every body is a valid image, so each is read, hashed, stored on disk and decoded to be checked. Prints the
server's resident memory before, its peak (the kernel's high-water mark, VmHWM, over the server's whole
life) and after, the statuses and the wall time. A benchmark, not a test: it asserts nothing.

    .venv/bin/python bench/memory.py [--uploads 8] [--mb 120]
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the test harness starts the processes

from tests.service.running import Service, content_digest, start_service


def _noise_png(megabytes: float) -> bytes:
    """A colour PNG of random pixels about ``megabytes`` MB large."""
    pixels = int(megabytes * 1e6 / 3)
    width = 6000
    rows = np.random.default_rng(7).integers(0, 256, size=(pixels // width, width, 3), dtype=np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(rows).save(buffer, format="PNG", compress_level=1)
    return buffer.getvalue()


def _memory_kib(pid: int) -> dict[str, int]:
    """The process's VmRSS and VmHWM (peak resident set) in KiB."""
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        name, _, value = line.partition(":")
        if name in ("VmRSS", "VmHWM"):
            fields[name] = int(value.split()[0])
    return fields


def _send(service: Service, key: str, capture_id: int, view: int, body: bytes) -> int:
    with httpx.Client(
        base_url=service.url, headers={"Authorization": f"Bearer {key}"}, timeout=600.0
    ) as client:
        return client.put(
            f"/v1/captures/{capture_id}/files/views/{view}/color.png",
            content=body,
            headers={"Content-Digest": content_digest(body)},
        ).status_code


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--uploads", type=int, default=8, help="bodies sent at once")
    parser.add_argument("--mb", type=float, default=120.0, help="size of each body, MB")
    options = parser.parse_args()
    body = _noise_png(options.mb)
    with tempfile.TemporaryDirectory(prefix="canopy-memory-bench-") as scratch:
        service = start_service(Path(scratch))
        try:
            keys = [service.create_key("capture") for _ in range(options.uploads)]
            manifest = {
                "format": "canopy-capture/1",
                "orchard": "bench",
                "row": "R1",
                "tree": "T1",
                "captured_at": "2026-11-25T10:00:00Z",
                "views": [f"views/{view}" for view in range(1, options.uploads + 1)],
            }
            with service.client() as client:
                capture_id = client.post("/v1/captures", content=json.dumps(manifest)).json()["id"]
            before = _memory_kib(service.server.pid)
            started = time.perf_counter()
            with ThreadPoolExecutor(options.uploads) as pool:
                statuses = list(
                    pool.map(
                        lambda view: _send(service, keys[view - 1], capture_id, view, body),
                        range(1, options.uploads + 1),
                    )
                )
            elapsed = time.perf_counter() - started
            after = _memory_kib(service.server.pid)
        finally:
            service.stop()
    print(
        f"{options.uploads} uploads at once of a {len(body) / 1e6:.1f} MB colour PNG "
        f"({options.uploads * len(body) / 1e6:.0f} MB in all), one capture key each"
    )
    print(f"  statuses: {dict(Counter(statuses))}; {elapsed:.1f} s")
    print(
        f"  API resident memory: before {before['VmRSS'] / 1024:.0f} MiB, peak {after['VmHWM'] / 1024:.0f} "
        f"MiB, after {after['VmRSS'] / 1024:.0f} MiB"
    )


if __name__ == "__main__":
    main()
