"""Registration benchmark: how far each view's pose is from the simulator's truth, balls alone and after ICP.

For each simulated tree, the true pose of view k relative to the first view comes from ground_truth.json's
camera_to_world; the pipeline's comes from the world_from_view poses it reports (after ICP, where
accepted) and from the ball registration alone (ICP disabled). Prints the median and 90th percentile of
translation (mm) and rotation (degrees) errors, and how often ICP was accepted and helped.

    .venv/bin/python bench/registration.py --count 12 [--seed 77] [--views 2]
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
from canopy_core.register import invert, pose_change
from canopy_core.simulate import simulate_capture


def _errors(args: tuple[Path, int, int]) -> list[dict]:
    folder, seed, views = args
    capture = simulate_capture(folder, seed=seed, n_views=views)
    truth = json.loads((capture / "ground_truth.json").read_text())["views"]
    try:
        refined = measure(capture)
        balls_only = measure(capture, overrides={"icp": {"enabled": False}})
    except CanopyError as exc:
        print(f"seed {seed}: failed: {exc}")
        return []
    rows = []
    first = refined.views[0].view
    true_first = np.asarray(truth[first]["camera_to_world"])
    for index in range(1, len(refined.views)):
        name = refined.views[index].view
        icp = refined.views[index].icp
        true_relative = invert(true_first) @ np.asarray(truth[name]["camera_to_world"])
        row = {
            "seed": seed,
            "view": name,
            "accepted": icp is not None and icp.accepted,
        }
        for label, result in (("balls", balls_only), ("icp", refined)):
            relative = invert(result.views[0].world_from_view) @ result.views[index].world_from_view
            row[label] = pose_change(true_relative, relative)
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=12)
    parser.add_argument("--seed", type=int, default=77)
    parser.add_argument("--views", type=int, default=2)
    parser.add_argument("--jobs", type=int, default=2)
    options = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="canopy-reg-") as scratch:
        work = [
            (Path(scratch) / f"t{i}", options.seed * 1000 + i, options.views) for i in range(options.count)
        ]
        with ProcessPoolExecutor(max_workers=options.jobs) as pool:
            rows = [row for rows in pool.map(_errors, work) for row in rows]
    print(f"{len(rows)} view pairs, {options.views} views per tree")
    print(f"{'poses':<8}{'trans p50 mm':>14}{'trans p90 mm':>14}{'rot p50 deg':>13}{'rot p90 deg':>13}")
    for label in ("balls", "icp"):
        translation = np.array([row[label][0] for row in rows]) * 1000
        rotation = np.array([row[label][1] for row in rows])
        print(
            f"{label:<8}{np.median(translation):>14.2f}{np.percentile(translation, 90):>14.2f}"
            f"{np.median(rotation):>13.3f}{np.percentile(rotation, 90):>13.3f}"
        )
    accepted = [row for row in rows if row["accepted"]]
    better = [row for row in accepted if row["icp"][0] < row["balls"][0]]
    print(
        f"ICP accepted for {len(accepted)} of {len(rows)} views; "
        f"closer to the truth in {len(better)} of those"
    )


if __name__ == "__main__":
    main()
