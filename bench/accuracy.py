"""Accuracy benchmark: the paper's Table 1 for simulated trees.

Simulates ``--count`` trees (two views each by default), measures each with the full pipeline and prints,
per mode (each single view, and the views merged) and per metric (H, W, D), the coefficient of
determination R², the RMSE in centimetres and the average relative error ARE in percent against the
simulator's ground truth, next to the paper's merged figures. A benchmark, not a test: it prints figures
and asserts nothing.

    .venv/bin/python bench/accuracy.py --count 30 [--seed 2026] [--views 2] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from canopy_core.errors import CanopyError
from canopy_core.measure import measure
from canopy_core.simulate import simulate_capture

METRICS = (("H", "height_m"), ("W", "width_m"), ("D", "thickness_m"))
PAPER_MERGED_ARE = {"H": 2.5, "W": 3.6, "D": 3.2}


def _measure_one(args: tuple[Path, int, int]) -> dict:
    folder, seed, views = args
    capture = simulate_capture(folder, seed=seed, n_views=views)
    truth = json.loads((capture / "ground_truth.json").read_text())
    try:
        result = measure(capture)
    except CanopyError as exc:
        return {"seed": seed, "error": str(exc)}
    modes = {name: metrics.to_dict() for name, metrics in result.modes.items()}
    return {"seed": seed, "truth": truth, "modes": modes}


def _table_row(predicted: np.ndarray, actual: np.ndarray) -> tuple[float, float, float]:
    residual = predicted - actual
    r2 = 1.0 - np.sum(residual**2) / np.sum((actual - actual.mean()) ** 2)
    rmse_cm = 100.0 * np.sqrt(np.mean(residual**2))
    are_pct = 100.0 * np.mean(np.abs(residual) / actual)
    return float(r2), float(rmse_cm), float(are_pct)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=30)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--views", type=int, default=2)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--details", action="store_true", help="Print every tree's errors too.")
    options = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="canopy-bench-") as scratch:
        work = [
            (Path(scratch) / f"tree_{i:03d}", options.seed * 1000 + i, options.views)
            for i in range(options.count)
        ]
        with ProcessPoolExecutor(max_workers=options.jobs) as pool:
            results = list(pool.map(_measure_one, work))

    failed = [r for r in results if "error" in r]
    done = [r for r in results if "error" not in r]
    print(f"{len(done)} of {len(results)} trees measured ({options.views} views each, seed {options.seed})")
    for failure in failed:
        print(f"  seed {failure['seed']}: FAILED: {failure['error']}")
    if not done:
        return
    mode_names = [name for name in done[0]["modes"] if name != "merged"] + ["merged"]
    print(f"\n{'mode':<10}{'metric':<8}{'R²':>8}{'RMSE cm':>10}{'ARE %':>8}{'paper ARE %':>13}")
    for mode in mode_names:
        for short, key in METRICS:
            predicted = np.array([r["modes"][mode][key] for r in done])
            actual = np.array([r["truth"][key] for r in done])
            r2, rmse_cm, are_pct = _table_row(predicted, actual)
            paper = f"{PAPER_MERGED_ARE[short]:.1f}" if mode == "merged" else ""
            print(f"{mode:<10}{short:<8}{r2:>8.3f}{rmse_cm:>10.2f}{are_pct:>8.2f}{paper:>13}")
    if options.details:
        print(f"\n{'seed':>8}" + "".join(f"{short + ' err cm':>12}" for short, _ in METRICS))
        for r in done:
            errors = [100 * (r["modes"]["merged"][key] - r["truth"][key]) for _, key in METRICS]
            print(f"{r['seed']:>8}" + "".join(f"{e:>12.2f}" for e in errors))


if __name__ == "__main__":
    main()
