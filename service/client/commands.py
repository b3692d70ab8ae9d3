"""``canopy upload`` and ``canopy watch``: the uploader with progress bars, a results table and a loop.

Progress bars (one for the row, one per capture, in bytes and files) appear on a terminal only; elsewhere
each capture gets one line. Errors name the capture folder and the file, on stderr, as do outages: the
first failed attempt is said at once, terminal or not. Before anything is sent, the server is asked who
the key is: an address that is not a Canopy service, a refused key, or ``--wait`` with a key that may not
read measurements ends the run at once with one line.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, DownloadColumn, Progress, TaskID, TextColumn, TransferSpeedColumn
from rich.table import Table

from service.client.receipts import RECEIPT_NAME, Receipt
from service.client.transport import RequestRefused, ServerUnreachable, ServerUnusable, Transport
from service.client.upload import (
    Uploader,
    UploadOutcome,
    files_to_send,
    find_captures,
    finished_jobs,
    receipt_complete,
    wait_for_jobs,
)

__all__ = ["run_upload", "run_watch"]


def _pending_bytes(folder: Path, server: str) -> int:
    acknowledged = Receipt.load(folder).for_server(server.rstrip("/")).files
    return sum(
        file.stat().st_size for path, file in files_to_send(folder).items() if path not in acknowledged
    )


def _report(console: Console, errors: Console, outcome: UploadOutcome) -> None:
    name = outcome.tree or str(outcome.folder)
    if outcome.error is not None:
        errors.print(f"[red]✗[/red] {outcome.folder}: {outcome.error}", highlight=False)
        return
    sent = f"{outcome.files_sent} file(s) sent ({outcome.bytes_sent / 1e6:.1f} MB)"
    there = f", {outcome.files_already_there} already there" if outcome.files_already_there else ""
    console.print(f"[green]✓[/green] {name}: {sent}{there}; job {outcome.job_id}", highlight=False)


def _upload_all(
    uploader: Uploader, folders: list[Path], console: Console, errors: Console
) -> list[UploadOutcome]:
    server = uploader.transport.server
    sizes = {folder: _pending_bytes(folder, server) for folder in folders}
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        DownloadColumn(),
        TransferSpeedColumn(),
        TextColumn("{task.fields[files]}"),
    )
    outcomes = []
    with Progress(*columns, console=console, disable=not console.is_terminal, transient=False) as progress:
        overall = progress.add_task("row", total=sum(sizes.values()), files=f"0/{len(folders)} captures")
        for done, folder in enumerate(folders):
            sending = len(files_to_send(folder))
            task = progress.add_task(folder.name, total=sizes[folder], files=f"0/{sending} files")
            sent = 0

            def advance(size: int, task: TaskID = task, sending: int = sending) -> None:
                nonlocal sent
                sent += 1
                progress.update(task, advance=size, files=f"{sent}/{sending} files")
                progress.advance(overall, size)

            outcome = uploader.upload(folder, on_bytes=advance)
            progress.update(overall, files=f"{done + 1}/{len(folders)} captures")
            progress.remove_task(task)
            _report(progress.console, errors, outcome)
            outcomes.append(outcome)
    return outcomes


def _measured(outcome: UploadOutcome) -> tuple[list[str], str]:
    """A finished job's H, W, D (metres, as text; empty when it failed) and a note: the failure's view,
    ball and message."""
    measurement = outcome.result.get("measurement")
    if measurement is not None:
        return [f"{measurement[key]:.3f}" for key in ("height_m", "width_m", "thickness_m")], ""
    error = outcome.result.get("job", {}).get("error") or {}
    note = error.get("message", outcome.result.get("refused", ""))
    where = " ".join(str(error[key]) for key in ("view", "color") if error.get(key))
    return ["", "", ""], f"{where}: {note}" if where else note


def _results_table(outcomes: list[UploadOutcome]) -> Table:
    table = Table("tree", "state", "H (m)", "W (m)", "D (m)", "note")
    for outcome in outcomes:
        values, note = _measured(outcome)
        table.add_row(outcome.tree, outcome.result.get("job", {}).get("state", ""), *values, note)
    return table


_USAGE = 2
"""Exit code of a run that could not start: a wrong address or a key that may not do what was asked."""


class _CannotStart(Exception):
    """The run cannot start; the message is said in one line and ``code`` is the exit code."""

    def __init__(self, message: str, code: int = _USAGE) -> None:
        super().__init__(message)
        self.code = code


def _connect(server: str, key: str, retry_for_s: float, errors: Console) -> tuple[Transport, list[str]]:
    """A transport to ``server`` whose key the server knows, and the key's scopes; outages are said on
    ``errors`` as they begin and end. Raises :class:`_CannotStart`."""
    try:
        transport = Transport(
            server,
            key,
            retry_for_s=retry_for_s,
            notice=lambda message: errors.print(message, highlight=False),
        )
    except ServerUnusable as exc:
        raise _CannotStart(str(exc)) from exc
    try:
        return transport, list(transport.identify()["key"]["scopes"])
    except ServerUnusable as exc:
        transport.close()
        raise _CannotStart(str(exc)) from exc
    except RequestRefused as exc:
        transport.close()
        raise _CannotStart(f"{transport.server} refused the key: {exc}") from exc
    except ServerUnreachable as exc:
        transport.close()
        raise _CannotStart(str(exc), code=1) from exc


def _may_read(scopes: list[str]) -> bool:
    return bool({"read", "admin"} & set(scopes))


def run_upload(root: Path, *, server: str, key: str, wait: bool, retry_for_s: float) -> int:
    """Upload every capture under ``root``; with ``wait``, print each tree's H, W, D as jobs finish.

    Returns the exit code: 0 when every capture is on the server (and, with ``wait``, measured), 2 when
    the run could not start (an address that is not a Canopy service, a refused key, ``wait`` with a key
    that may not read), else 1.
    """
    console, errors = Console(soft_wrap=True), Console(stderr=True, soft_wrap=True)
    folders = find_captures(root)
    if not folders:
        errors.print(f"no capture folder (with capture.json) under {root}")
        return 1
    try:
        transport, scopes = _connect(server, key, retry_for_s, errors)
    except _CannotStart as exc:
        errors.print(f"[red]✗[/red] {exc}", highlight=False)
        return exc.code
    if wait and not _may_read(scopes):
        transport.close()
        errors.print(
            "[red]✗[/red] --wait shows the measurements, which needs a key with the read scope; this key "
            f"has {', '.join(scopes)}. Upload without --wait, or with a key that has capture and read",
            highlight=False,
        )
        return _USAGE
    finished: list[UploadOutcome] = []
    try:
        outcomes = _upload_all(Uploader(transport), folders, console, errors)
        failed = sum(outcome.error is not None for outcome in outcomes)
        if wait:
            for outcome in wait_for_jobs(transport, outcomes):
                finished.append(outcome)
                state = outcome.result["job"]["state"]
                console.print(f"{outcome.tree}: measurement {state}", highlight=False)
                failed += state != "succeeded"
    except (ServerUnreachable, RequestRefused) as exc:
        errors.print(f"[red]✗[/red] waiting for the measurements: {exc}", highlight=False)
        failed = 1
    finally:
        transport.close()
        if finished:
            console.print(_results_table(finished))
    return 1 if failed else 0


def _snapshot(folder: Path) -> tuple[tuple[str, int, int], ...]:
    """Every file of the folder (the receipt aside) with its size and time: equal snapshots across scans
    mean nothing is being written, whatever the files' own times say (a copy keeps the originals')."""
    ours = RECEIPT_NAME.removesuffix(".json")  # the receipt and its temporary files
    return tuple(
        (path.relative_to(folder).as_posix(), status.st_size, status.st_mtime_ns)
        for path in sorted(folder.rglob("*"))
        if not path.name.startswith(ours) and path.is_file() and (status := path.stat())
    )


def _say_measured(console: Console, errors: Console, outcome: UploadOutcome) -> None:
    values, note = _measured(outcome)
    if outcome.result["job"]["state"] == "succeeded" and all(values):
        height, width, thickness = values
        console.print(f"{outcome.tree}: measured H {height} m, W {width} m, D {thickness} m", highlight=False)
    else:
        errors.print(f"[red]✗[/red] {outcome.tree}: measurement failed: {note}", highlight=False)


def run_watch(root: Path, *, server: str, key: str, interval_s: float, settle_s: float) -> int:
    """Upload capture folders under ``root`` as they appear, until interrupted; returns the exit code.

    A folder is sent once it has stayed the same (its files, sizes and times) for ``settle_s`` (the
    capture software has finished writing it). While the server cannot be reached, the scan stops and
    starts again at the next one (the outage is said as it begins and ends); a folder the checks or the
    server refuse is reported once, and again only after it changes. A folder that changes after its
    upload is looked at again. With a key that may read, each measurement is printed as it completes.
    """
    console, errors = Console(soft_wrap=True), Console(stderr=True, soft_wrap=True)
    _stop_on_signals()
    try:
        transport, scopes = _watch_connect(server, key, interval_s, errors)
    except _CannotStart as exc:
        errors.print(f"[red]✗[/red] {exc}", highlight=False)
        return exc.code
    except KeyboardInterrupt:
        console.print("stopped")
        return 0
    uploader = Uploader(transport, verify_done=False)
    seen: dict[Path, tuple[tuple[tuple[str, int, int], ...], float]] = {}
    refused: dict[Path, tuple[tuple[str, int, int], ...]] = {}
    measuring: list[UploadOutcome] = []
    console.print(f"watching {root} for captures to send to {transport.server} (Ctrl-C stops)")
    try:
        while True:
            for folder in find_captures(root):
                if receipt_complete(folder, transport.server):
                    continue
                snapshot = _snapshot(folder)
                if seen.get(folder, ((), 0.0))[0] != snapshot:
                    seen[folder] = (snapshot, time.monotonic())
                if time.monotonic() - seen[folder][1] < settle_s or refused.get(folder) == snapshot:
                    continue
                try:
                    outcome = uploader.upload(folder)
                except Exception as exc:  # one folder's surprise must not stop a day's watching
                    errors.print(f"[red]✗[/red] {folder}: {type(exc).__name__}: {exc}", highlight=False)
                    refused[folder] = snapshot
                    continue
                if outcome.retryable:
                    errors.print(
                        f"… {folder}: not sent yet, the server is out of reach for now; the next scan, in "
                        f"{interval_s:g} s, tries again",
                        highlight=False,
                    )
                    break  # the other folders would only wait for the server too
                _report(console, errors, outcome)
                if outcome.error is not None:
                    refused[folder] = snapshot
                elif outcome.job_id is not None and _may_read(scopes):
                    measuring.append(outcome)
            measuring = _report_measured(transport, measuring, console, errors)
            time.sleep(interval_s)
    except KeyboardInterrupt:
        console.print("stopped")
    finally:
        transport.close()
    return 0


def _stop_on_signals() -> None:
    """Ctrl-C (SIGINT) and a service manager's SIGTERM both end a watch between two steps, as
    KeyboardInterrupt: also when it was started with SIGINT ignored (in the background of a script),
    which Python would otherwise keep, so that nothing but SIGKILL would stop it."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.default_int_handler)


def _watch_connect(server: str, key: str, interval_s: float, errors: Console) -> tuple[Transport, list[str]]:
    """:func:`_connect` for a watch, which may start before the laptop is in range: it keeps trying."""
    while True:
        try:
            return _connect(server, key, max(interval_s, 30.0), errors)
        except _CannotStart as exc:
            if exc.code != 1:
                raise
            errors.print(f"… {exc}; trying again in {interval_s:g} s", highlight=False)
            time.sleep(interval_s)


def _report_measured(
    transport: Transport, measuring: list[UploadOutcome], console: Console, errors: Console
) -> list[UploadOutcome]:
    """Print the measurements that completed since the last scan; returns the jobs still running."""
    if not measuring:
        return measuring
    try:
        finished, running = finished_jobs(transport, measuring)
    except ServerUnreachable:
        return measuring  # said as the outage began; asked again at the next scan
    except RequestRefused as exc:
        errors.print(f"[red]✗[/red] cannot follow the measurements: {exc}", highlight=False)
        return []
    for outcome in finished:
        _say_measured(console, errors, outcome)
    return running
