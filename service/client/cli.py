"""The capture laptop's commands: ``upload`` and ``watch``. They need only the base install (the core and
httpx); they join the ``canopy`` command through the ``canopy.commands`` entry point (pyproject.toml).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

__all__ = ["app"]

app = typer.Typer(rich_markup_mode=None)

ServerOpt = Annotated[str, typer.Option("--server", help="The service's address, e.g. http://10.0.0.5:8000.")]
KeyOpt = Annotated[
    str,
    typer.Option(
        "--key", envvar="CANOPY_KEY", help="API key (capture scope; read too for --wait).", show_default=False
    ),
]
RootArg = Annotated[
    Path, typer.Argument(metavar="ROOT", help="A capture folder, or a folder holding capture folders.")
]


@app.command()
def upload(
    root: RootArg,
    server: ServerOpt,
    key: KeyOpt,
    wait: Annotated[
        bool, typer.Option("--wait", help="Then wait for the measurements and show H, W, D.")
    ] = False,
    retry_for: Annotated[
        float, typer.Option(min=1, help="Keep retrying a failing request this long, seconds.")
    ] = 300.0,
) -> None:
    """Send every capture under ROOT that the server does not have yet, and start its measurement.

    Each capture is checked first (nothing invalid is sent); a receipt in each folder records what the server
    acknowledged, so a repeated, killed or interrupted upload resumes without sending anything twice.
    """
    from service.client.commands import run_upload

    raise typer.Exit(run_upload(root, server=server, key=key, wait=wait, retry_for_s=retry_for))


@app.command()
def watch(
    root: RootArg,
    server: ServerOpt,
    key: KeyOpt,
    interval: Annotated[float, typer.Option(min=0.1, help="Seconds between scans of ROOT.")] = 10.0,
    settle: Annotated[
        float, typer.Option(min=0, help="A capture is sent once unchanged for this many seconds.")
    ] = 5.0,
) -> None:
    """Keep running: send new capture folders under ROOT as they appear, and when the network is back."""
    from service.client.commands import run_watch

    raise typer.Exit(run_watch(root, server=server, key=key, interval_s=interval, settle_s=settle))
