"""The ``canopy`` command line: measure a capture offline, check its balls, simulate captures.

Commands import the measurement pipeline only when they run, so ``canopy --help`` stays instant. Every
error the core raises on purpose is printed as one line on stderr with exit code 2.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import typer

from canopy_core.errors import CanopyError
from canopy_core.extras import require_extra

__all__ = ["COMMANDS_GROUP", "app", "command_line", "main"]

app = typer.Typer(
    name="canopy",
    help="Measure fruit-tree canopies (height, width, crown thickness) from multi-view RGB-D captures.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # plain help: no "<bool>" after every flag, readable in any terminal
)


def _print_version(asked: bool) -> None:
    if asked:
        from canopy_core import __version__

        typer.echo(f"canopy {__version__}")
        raise typer.Exit()


@app.callback()
def _options(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_print_version, is_eager=True, help="Print the version and exit."),
    ] = False,
) -> None:
    """Measure fruit-tree canopies (height, width, crown thickness) from multi-view RGB-D captures."""


CaptureArg = Annotated[
    Path, typer.Argument(metavar="CAPTURE", help="Capture folder (the one holding capture.json).")
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print one JSON object instead of a summary.")]
SetOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--set",
        metavar="KEY=VALUE",
        help="Override one measurement setting for this run, e.g. --set metrics.max_thin_top_m=0.4 "
        "(repeatable; KEY is the setting's dotted path, VALUE is JSON). Every setting, its default and "
        "meaning: canopy settings.",
    ),
]


def settings_overrides(assignments: list[str] | None) -> dict[str, Any] | None:
    """The nested overrides of ``--set KEY=VALUE`` options (``metrics.max_thin_top_m=0.4`` becomes
    ``{"metrics": {"max_thin_top_m": 0.4}}``), the shape a service job's ``config`` has, combined as the
    settings combine it (:func:`canopy_core.config.deep_merge`: where two set one setting, the later wins);
    None for none.

    VALUE is JSON: a number, true or false, a list, an object. Whether the setting exists and its value is
    valid is the configuration's to say, naming the setting.

    Raises
    ------
    CanopyError
        An assignment without ``=``, with an empty part of its dotted KEY, or whose VALUE is not JSON.
    """
    from canopy_core.config import deep_merge

    if not assignments:
        return None
    overrides: dict[str, Any] = {}
    for assignment in assignments:
        key, equals, text = assignment.partition("=")
        path = [part.strip() for part in key.split(".")]
        if not equals or not all(path):
            raise CanopyError(
                f"--set {assignment!r}: expected KEY=VALUE with KEY a setting's dotted path, "
                "e.g. metrics.max_thin_top_m=0.4",
                field="--set",
            )
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            raise CanopyError(
                f"--set {assignment!r}: {text.strip()!r} is not a JSON value; write a number as 0.4, a "
                'switch as true or false, a list as ["red", "blue"]',
                field="--set",
            ) from None
        for part in reversed(path):
            value = {part: value}
        overrides = deep_merge(overrides, value)
    return overrides


def _print_json(document: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(document, indent=1, allow_nan=False) + "\n")


@app.command()
def measure(
    capture: CaptureArg,
    as_json: JsonOpt = False,
    cloud: Annotated[
        Path | None,
        typer.Option("--cloud", help="Write the fused, cropped cloud (world frame) as binary PLY."),
    ] = None,
    assignments: SetOpt = None,
    processes: Annotated[
        int | None,
        typer.Option(
            "--processes",
            min=1,
            help="Views filtered and searched for balls at once, and their regions of interest cut, each "
            "in a process of its own (default: one per CPU; 1: one at a time). The figures are the same "
            "either way.",
        ),
    ] = None,
) -> None:
    """Register the views of a capture and measure the tree: height, width, thickness and more."""
    from canopy_core.cloud_io import write_ply
    from canopy_core.measure import measure as run_measure

    if cloud is not None and not cloud.parent.resolve().is_dir():
        raise CanopyError(f"cannot write the cloud: folder {cloud.parent} does not exist", field="--cloud")
    result = run_measure(capture, overrides=settings_overrides(assignments), processes=processes)
    if cloud is not None:
        try:
            write_ply(cloud, result.cloud)
        except OSError as exc:
            raise CanopyError(f"cannot write the cloud to {cloud}: {exc}", field="--cloud") from exc
    if as_json:
        sys.stdout.write(result.to_json(indent=1) + "\n")
        return
    identity = result.manifest
    typer.echo(f"{identity.orchard} / {identity.row} / {identity.tree}  ({identity.captured_at})")
    typer.echo(f"{'mode':<12}{'H (m)':>9}{'W (m)':>9}{'D (m)':>9}{'points':>10}")
    for name, metrics in result.modes.items():
        typer.echo(
            f"{name:<12}{metrics.height_m:>9.3f}{metrics.width_m:>9.3f}{metrics.thickness_m:>9.3f}"
            f"{metrics.points:>10}"
        )


@app.command()
def settings() -> None:
    """Print every measurement setting, its default and meaning (Markdown): what --set may change."""
    from canopy_core.settings_reference import settings_reference

    sys.stdout.write(settings_reference())


@app.command()
def balls(
    capture: CaptureArg,
    as_json: JsonOpt = False,
    preview: Annotated[
        Path | None,
        typer.Option(
            "--preview",
            help="Write each view's colour image with its balls drawn to DIR (views/1 as views_1.png).",
        ),
    ] = None,
    show_all: Annotated[
        bool, typer.Option("--all", help="List every rejected sphere (by default 3 per colour, 5 in JSON).")
    ] = False,
    assignments: SetOpt = None,
) -> None:
    """Show per view and colour the ball chosen, as the measurement chooses it, and why each other sphere
    was not (radius, points, residual, coverage, colour, floating, taken, inconsistent).

    When the selection fails, what each view shows on its own is still printed, then the error (exit 2).
    """
    from canopy_core.ball_preview import ball_report, draw_ball_preview
    from canopy_core.capture import load_capture
    from canopy_core.measure import config_for, view_evidence

    overrides = settings_overrides(assignments)
    if preview is not None:
        try:
            preview.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CanopyError(
                f"cannot create the preview folder {preview}: {exc}", field="--preview"
            ) from exc
        if not os.access(preview, os.W_OK):
            raise CanopyError(f"cannot write to the preview folder {preview}", field="--preview")
    loaded = load_capture(capture)
    config = config_for(loaded.manifest, overrides)
    evidence = view_evidence(loaded.views, config, processes=None)
    report = ball_report(
        [view.balls for view in evidence], config.balls, grounds=[view.ground for view in evidence]
    )
    if preview is not None:
        from PIL import Image

        for view, choice in zip(loaded.views, report.choices, strict=True):
            path = preview / f"{view.name.replace('/', '_')}.png"
            try:
                Image.fromarray(draw_ball_preview(view, choice, config.balls)).save(path)
            except OSError as exc:
                raise CanopyError(f"cannot write the preview {path}: {exc}", field="--preview") from exc
    if as_json:
        _print_json(report.to_dict(limit=None if show_all else 5))
    else:
        for line in report.lines(limit=None if show_all else 3):
            typer.echo(line)
    if report.error is not None:
        raise report.error


@app.command()
def simulate(
    out: Annotated[Path, typer.Argument(metavar="OUT", help="Folder to write the captures into.")],
    seed: Annotated[int, typer.Option(help="Random seed; the same seed writes the same captures.")] = 0,
    count: Annotated[int, typer.Option(min=1, help="Number of trees.")] = 1,
    views: Annotated[int, typer.Option(min=1, help="Views per tree.")] = 2,
    scenario: Annotated[
        str,
        typer.Option(
            help="Scene family: green (plain), dry (straw, soil, mulch, fallen leaves), fruit (apples), "
            "wires (trellis), weeds (weeds and suckers), harsh (hard sun, shadows), mixed (any of them)."
        ),
    ] = "green",
    sensor: Annotated[
        str,
        typer.Option(
            help="RGB-D sensor: kinect-v2, azure-kinect-nfov-binned (320x288 depth) or azure-kinect-nfov "
            "(640x576 depth)."
        ),
    ] = "kinect-v2",
    slope_deg: Annotated[
        float | None,
        typer.Option(
            help="Ground slope in degrees, downhill in a random direction (a hillside orchard; trees stand "
            "upright). Default: nearly level, at most 0.5 degrees."
        ),
    ] = None,
    lean_deg: Annotated[
        float | None,
        typer.Option(
            help="Lean every tree this far from vertical from its foot, trunk and crown, in a random "
            "direction (a slanted planting, or a tree pushed over by wind). Default: trunks stand upright."
        ),
    ] = None,
    stake: Annotated[
        bool,
        typer.Option(
            help="Stand a support stake beside every trunk (a 2 cm pole, its top up to 0.5 m above or below "
            "the crown's), as young tall-spindle trees have."
        ),
    ] = False,
    pitch_deg: Annotated[
        float | None,
        typer.Option(
            help="Hold every camera this many degrees up from level (negative: down), as a crew that does "
            "not aim it at the tree: the tree may run out of the image, the balls never do. Default: each "
            "camera is aimed to frame the whole tree."
        ),
    ] = None,
    near_posts: Annotated[
        bool,
        typer.Option(
            help="Stand a trellis post on each side of every tree 0.5-1.4 m from its trunk, within the "
            "crown's reach (2.0-3.8 m tall, or the trellis's height), as rows with posts between trees a "
            "metre or two apart have. Default: posts stand at least 1.6 m from the trunk."
        ),
    ] = False,
) -> None:
    """Write synthetic captures of procedural apple trees, each with its ground_truth.json."""
    require_extra("sim", "simulate")
    from canopy_core.simulate import NoLayout, simulate_captures
    from canopy_core.simulate.camera import parse_sensor
    from canopy_core.simulate.scenario import parse_scenario

    try:
        family = parse_scenario(scenario)
        parse_sensor(sensor)
    except ValueError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    try:
        paths = simulate_captures(
            out,
            seed=seed,
            count=count,
            n_views=views,
            scenario=family,
            sensor=sensor,
            slope_deg=slope_deg,
            lean_deg=lean_deg,
            stake=stake,
            pitch_deg=pitch_deg,
            near_posts=near_posts,
        )
    except (FileExistsError, ValueError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    except NoLayout as exc:
        typer.echo(f"error: {exc}; try another --seed into a new folder", err=True)
        raise typer.Exit(1) from exc
    for path in paths:
        typer.echo(str(path))


COMMANDS_GROUP = "canopy.commands"
"""The entry-point group through which other parts of the install add their commands to ``canopy``: the
capture client (``upload``, ``watch``) and the service (``serve``, ``worker``, ``up``, ...). Each entry
is a Typer app whose commands join the top level."""


def command_line(arguments: Sequence[str] | None = None) -> typer.Typer:
    """The whole ``canopy`` command: the core's commands and every installed part's; only the core's when
    the command asked for (the first of ``arguments``, by default the process's) is one of them, so that
    ``canopy measure`` does not look the parts up (about 20 ms of every start, reading the install's
    metadata and importing the parts' command modules)."""
    arguments = sys.argv[1:] if arguments is None else arguments
    core = {
        command.name or getattr(command.callback, "__name__", "").lower().replace("_", "-")
        for command in app.registered_commands
    }
    if arguments and arguments[0] in core:
        return app
    from importlib.metadata import entry_points

    for entry in sorted(entry_points(group=COMMANDS_GROUP), key=lambda entry: entry.name):
        app.add_typer(entry.load())
    return app


def main() -> None:
    """Console-script entry point: run the command, turning the core's errors into one line and exit 2."""
    try:
        command_line()()
    except CanopyError as exc:
        typer.echo(f"error: {exc}", err=True)
        sys.exit(2)


if __name__ == "__main__":
    main()
