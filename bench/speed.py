"""Speed benchmark: wall time of ``canopy measure --json`` on a two-view native Kinect v2 capture.

Runs the real command (process start, imports, loading, the whole pipeline, JSON output) ``--repeat`` times
and prints each time and the median, and the median CPU time it and the processes it forked used, in user code
and in the kernel (page faults, forks); then the in-process time per stage (the median of ``--repeat`` runs in
one process, after one to warm up). Each version runs from bytecode, as an installed package does (pip
compiles it on install; an editable install on first import): compiled into a scratch folder by one untimed
run, whatever ``PYTHONDONTWRITEBYTECODE`` says, since compiling 11 000 lines of source at every start (about
0.2 s here) is no part of what a user waits for. The capture is the simulator's plain green scene, the
reference of the speed figures since 2026-11-22; ``--scenario mixed`` times a cluttered orchard instead, whose
balls take longer to find (many more spheres of their colours to weigh).

With ``--against REV`` the same capture is also measured by the code of git revision ``REV`` (checked out
in a temporary worktree, run with this environment's packages), the two alternating run by run, each first
in every other pair of runs: the honest way to compare two versions, since a shared or throttled machine's
speed drifts by tens of per cent within an hour and by more from day to day. Printed are the ratio of the
medians and, steadier, the median of the ratios pair by pair (each run of this code over the other
version's run next to it, so that a drift slower than a pair of runs cancels), with its 95 % bootstrap
interval: a ratio whose interval holds 1 shows no clear difference. Then each version's start (a process
importing what the command imports before it measures) and its in-process time per stage (the median of
``--repeat`` measurements, each in a process of its own after one to warm up), the versions taking turns
as the runs do, are printed side by side: where the two differ.

    .venv/bin/python bench/speed.py [--repeat 5] [--seed 1] [--scenario green|mixed|...] [--against 73286c1]
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from canopy_core.measure import measure

REPOSITORY = Path(__file__).resolve().parent.parent


def _as_the_command() -> dict[str, Any]:
    """What ``canopy measure`` passes to :func:`measure` beyond the capture: the views searched at once
    (one process per CPU), where the code has that choice (the older revisions compared do not)."""
    return {"processes": None} if "processes" in inspect.signature(measure).parameters else {}


_AS_THE_COMMAND = _as_the_command()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--scenario",
        default="green",
        help="The simulated scene's family (default green, the reference; mixed for a cluttered orchard).",
    )
    parser.add_argument(
        "--against", metavar="REV", help="Also time git revision REV, alternating with this code."
    )
    parser.add_argument("--stages-of", type=Path, help=argparse.SUPPRESS)  # run by _stage_times
    options = parser.parse_args()
    if options.repeat < 1:
        parser.error("--repeat must be at least 1")
    if options.stages_of is not None:
        measure(options.stages_of)  # to warm up: imports done, caches filled
        print(json.dumps(measure(options.stages_of, **_AS_THE_COMMAND).timings_s))
        return
    # Imported here, not above: the stage timings above run on another revision's package, which may
    # lack what this revision's simulator offers.
    from canopy_core.simulate import Scenario, simulate_capture

    if options.scenario not in {scenario.value for scenario in Scenario}:
        parser.error(f"--scenario must be one of {', '.join(scenario.value for scenario in Scenario)}")
    with tempfile.TemporaryDirectory(prefix="canopy-speed-") as scratch:
        # Every command below runs from bytecode kept here (written by its version's first run).
        os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
        os.environ["PYTHONPYCACHEPREFIX"] = str(Path(scratch) / "bytecode")
        capture = simulate_capture(
            Path(scratch) / "tree", seed=options.seed, n_views=2, native_color=True, scenario=options.scenario
        )
        print(
            "canopy measure --json, two-view Kinect v2 capture (512x424 depth, 1920x1080 colour), "
            f"{options.scenario} scene, seed {options.seed}"
        )
        if options.against is None:
            _timed_run(capture, source=None)  # compiles the bytecode
            _print_runs("this code", [_timed_run(capture, source=None) for _ in range(options.repeat)])
        else:
            other = Path(scratch) / "against"
            worktree = ["git", "-C", str(REPOSITORY), "worktree"]
            added = subprocess.run(
                [*worktree, "add", "--detach", "--quiet", str(other), options.against],
                capture_output=True,
                text=True,
            )
            if added.returncode != 0:
                sys.exit(f"cannot check out {options.against} to compare with: {added.stderr.strip()}")
            try:
                runs: dict[str, list[_Run]] = {"this code": [], options.against: []}
                _timed_run(capture, source=None), _timed_run(capture, source=other)  # compile the bytecode
                versions = [("this code", None), (options.against, other)]
                for turn in range(options.repeat):
                    for name, source in _in_turn(versions, turn):
                        runs[name].append(_timed_run(capture, source=source))
                for name, version_runs in runs.items():
                    _print_runs(name, version_runs)
                ratio = _median_wall(runs["this code"]) / _median_wall(runs[options.against])
                paired = _paired(runs["this code"], runs[options.against])
                print(f"this code / {options.against}: {ratio:.2f} (the medians); {paired}")
                starts: dict[str, list[float]] = {"this code": [], options.against: []}
                for turn in range(3 * options.repeat):  # short and noisy: three times as many
                    for name, source in _in_turn(versions, turn):
                        starts[name].append(_start_time(source=source))
                print(
                    "the command's start (the core's imports, s, median): "
                    + ", ".join(f"{name} {statistics.median(times):.3f}" for name, times in starts.items())
                )
                stage_runs: dict[str, list[dict[str, float]]] = {"this code": [], options.against: []}
                for turn in range(options.repeat):  # each in a process of its own
                    for name, source in _in_turn(versions, turn):
                        stage_runs[name].append(_stage_times(capture, source=source))
            finally:
                subprocess.run([*worktree, "remove", "--force", str(other)], check=True)
            _print_stages({name: _median_stages(times) for name, times in stage_runs.items()})
            return
        measure(capture)  # to warm up: imports done, caches filled
        stages_s = _median_stages(
            [measure(capture, **_AS_THE_COMMAND).timings_s for _ in range(options.repeat)]
        )
        print("in-process stages (s, median): " + ", ".join(f"{k} {v:.3f}" for k, v in stages_s.items()))


def _median_stages(runs: list[dict[str, float]]) -> dict[str, float]:
    """Each stage's median time over ``runs`` (each a measurement's ``timings_s``), seconds, and the
    total's; a stage a run lacks counts 0."""
    names = list(dict.fromkeys(name for run in runs for name in run))
    stages = {name: statistics.median(run.get(name, 0.0) for run in runs) for name in names}
    return {**stages, "total": statistics.median(sum(run.values()) for run in runs)}


def _stage_times(capture: Path, *, source: Path | None) -> dict[str, float]:
    """One measurement's in-process time per stage, seconds, on this code or on the source tree
    ``source``, in a process of its own after one measurement to warm up."""
    try:
        done = subprocess.run(
            [sys.executable, __file__, "--stages-of", str(capture)],
            check=True,
            capture_output=True,
            text=True,
            env=_environment(source),
        )
    except subprocess.CalledProcessError as failed:
        sys.exit(f"timing the stages of {source or 'this code'} failed:\n{failed.stderr[-2000:]}")
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def _print_stages(stages: dict[str, dict[str, float]]) -> None:
    """The versions' in-process stage times side by side (a stage one version lacks shows as 0)."""
    names = list(dict.fromkeys(name for times in stages.values() for name in times if name != "total"))
    width = max(12, *(len(version) + 2 for version in stages))
    print("in-process stages (s, median):")
    print(f"  {'stage':<10}" + "".join(f"{version:>{width}}" for version in stages))
    for name in [*names, "total"]:
        print(f"  {name:<10}" + "".join(f"{times.get(name, 0.0):>{width}.3f}" for times in stages.values()))


@dataclass(frozen=True)
class _Run:
    """One ``canopy measure --json``: how long it took, and the CPU it used."""

    wall_s: float
    user_s: float
    system_s: float
    """The CPU time in user code and in the kernel (page faults, forks, memory), seconds, of the command and
    of the processes it forked for its views."""


def _timed_run(capture: Path, *, source: Path | None) -> _Run:
    """One ``canopy measure --json``, on this code or on the source tree ``source`` (put first on the
    import path, before the installed package)."""
    canopy = Path(sys.executable).with_name("canopy")
    environment = _environment(source)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    subprocess.run(
        [str(canopy), "measure", str(capture), "--json"], check=True, capture_output=True, env=environment
    )
    wall_s = time.perf_counter() - started
    # The command waits for the processes it forks, so their time is counted in its own.
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return _Run(wall_s, after.ru_utime - before.ru_utime, after.ru_stime - before.ru_stime)


def _median_wall(runs: list[_Run]) -> float:
    """The median wall time of ``runs``, seconds."""
    return statistics.median(run.wall_s for run in runs)


def _in_turn(versions: list[tuple[str, Path | None]], turn: int) -> list[tuple[str, Path | None]]:
    """The versions (name, source tree) in the order they run in pair ``turn``: each first in every other
    pair, so that whatever running first does to a run (a colder file cache, a busier machine) falls on
    both alike."""
    return versions if turn % 2 == 0 else versions[::-1]


_BOOTSTRAP_RESAMPLES = 10_000
"""Resamples of the run-by-run ratios that :func:`_median_interval` draws."""

_MIN_PAIRS_FOR_INTERVAL = 5
"""Fewer pairs of runs than this give no interval: a bootstrap of two or three values is those values."""


def _paired(mine: list[_Run], theirs: list[_Run]) -> str:
    """The median of the ratios of this code's runs (``mine``) to the other version's (``theirs``), pair
    by pair, and its 95 % bootstrap interval when there are enough pairs."""
    ratios = [a.wall_s / b.wall_s for a, b in zip(mine, theirs, strict=True)]
    said = f"run by run {statistics.median(ratios):.2f}"
    if len(ratios) < _MIN_PAIRS_FOR_INTERVAL:
        return f"{said} (too few pairs for an interval: {len(ratios)})"
    low, high = _median_interval(ratios)
    return f"{said}, 95 % bootstrap interval {low:.2f}-{high:.2f} ({len(ratios)} pairs)"


def _median_interval(values: list[float]) -> tuple[float, float]:
    """The 95 % percentile-bootstrap interval of the median of ``values`` (seeded: the same runs print the
    same interval)."""
    rng = np.random.default_rng(0)
    drawn = rng.choice(np.asarray(values), size=(_BOOTSTRAP_RESAMPLES, len(values)), replace=True)
    low, high = np.percentile(np.median(drawn, axis=1), [2.5, 97.5])
    return float(low), float(high)


def _start_time(*, source: Path | None) -> float:
    """Seconds a process takes to start and import what ``canopy measure`` imports before it measures, on
    this code or on the source tree ``source``: the part of a run's time that is no measuring.

    The process runs in the source tree's folder (this repository's for this code): ``python -c`` puts its
    working folder first on the import path, before ``PYTHONPATH``, so run from this repository it would
    import this code whatever ``source`` is (until 2026-12-07 it did: both versions' starts were this
    code's)."""
    environment = _environment(source)
    started = time.perf_counter()
    subprocess.run(
        [sys.executable, "-c", "import canopy_core.cli, canopy_core.measure, canopy_core.cloud_io"],
        check=True,
        capture_output=True,
        env=environment,
        cwd=source if source is not None else REPOSITORY,
    )
    return time.perf_counter() - started


def _environment(source: Path | None) -> dict[str, str]:
    """This process's environment, with the source tree ``source`` (if any) first on the import path."""
    environment = dict(os.environ)
    if source is not None:
        environment["PYTHONPATH"] = os.pathsep.join(
            filter(None, [str(source), environment.get("PYTHONPATH")])
        )
    return environment


def _print_runs(name: str, runs: list[_Run]) -> None:
    """Each run's wall time and the median; the median CPU time, in user code and in the kernel: a
    version whose views run at once uses more CPU than its wall time, one that runs them one after the
    other less."""
    user_s = statistics.median(run.user_s for run in runs)
    system_s = statistics.median(run.system_s for run in runs)
    print(
        f"{name}: runs (s) "
        + ", ".join(f"{run.wall_s:.2f}" for run in runs)
        + f"; median {_median_wall(runs):.2f} s; CPU median {user_s:.2f} s user, {system_s:.2f} s system"
    )


if __name__ == "__main__":
    main()
