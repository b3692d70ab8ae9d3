"""Speed benchmark: wall time of ``canopy measure --json`` on a two-view native Kinect v2 capture.

Runs the real command (process start, imports, loading, the whole pipeline, JSON output) ``--repeat`` times
and prints each time and the median; then the in-process time per stage of one run.

    .venv/bin/python bench/speed.py [--repeat 5] [--seed 1]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from canopy_core.measure import measure
from canopy_core.simulate import simulate_capture


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--seed", type=int, default=1)
    options = parser.parse_args()
    canopy = Path(sys.executable).with_name("canopy")
    with tempfile.TemporaryDirectory(prefix="canopy-speed-") as scratch:
        capture = simulate_capture(Path(scratch) / "tree", seed=options.seed, n_views=2, native_color=True)
        times = []
        for _ in range(options.repeat):
            started = time.perf_counter()
            subprocess.run([str(canopy), "measure", str(capture), "--json"], check=True, capture_output=True)
            times.append(time.perf_counter() - started)
        print("canopy measure --json, two-view Kinect v2 capture (512x424 depth, 1920x1080 colour)")
        print("runs (s): " + ", ".join(f"{t:.2f}" for t in times))
        print(f"median of {len(times)}: {statistics.median(times):.2f} s")
        result = measure(capture)
        print("in-process stages (s): " + ", ".join(f"{k} {v:.3f}" for k, v in result.timings_s.items()))


if __name__ == "__main__":
    main()
