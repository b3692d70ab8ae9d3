"""``canopy upload`` and ``canopy watch``: the uploader with progress bars, a results table and a loop.

Progress bars (one for the row, one per capture, in bytes and files) appear on a terminal only; elsewhere
each capture gets one line. Errors name the capture folder and the file, on stderr.
"""

from __future__ import annotations

import time
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, DownloadColumn, Progress, TaskID, TextColumn, TransferSpeedColumn
from rich.table import Table

from service.client.receipts import RECEIPT_NAME, Receipt
from service.client.transport import RequestRefused, ServerUnreachable, Transport
from service.client.upload import (
    Uploader,
    UploadOutcome,
    files_to_send,
    find_captures,
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


def _results_table(outcomes: list[UploadOutcome]) -> Table:
    table = Table("tree", "state", "H (m)", "W (m)", "D (m)", "note")
    for outcome in outcomes:
        job = outcome.result.get("job", {})
        measurement = outcome.result.get("measurement")
        if measurement is not None:
            values = [f"{measurement[key]:.3f}" for key in ("height_m", "width_m", "thickness_m")]
            note = ""
        else:
            values = ["", "", ""]
            error = job.get("error") or {}
            note = error.get("message", outcome.result.get("refused", ""))
            where = " ".join(str(error[key]) for key in ("view", "color") if error.get(key))
            note = f"{where}: {note}" if where else note
        table.add_row(outcome.tree, job.get("state", ""), *values, note)
    return table


def run_upload(root: Path, *, server: str, key: str, wait: bool, retry_for_s: float) -> int:
    """Upload every capture under ``root``; with ``wait``, print each tree's H, W, D as jobs finish.

    Returns the exit code: 0 when every capture is on the server (and, with ``wait``, measured), else 1.
    """
    console, errors = Console(soft_wrap=True), Console(stderr=True, soft_wrap=True)
    folders = find_captures(root)
    if not folders:
        errors.print(f"no capture folder (with capture.json) under {root}")
        return 1
    transport = Transport(server, key, retry_for_s=retry_for_s)
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


def run_watch(root: Path, *, server: str, key: str, interval_s: float, settle_s: float) -> None:
    """Upload capture folders under ``root`` as they appear, until interrupted.

    A folder is sent once it has stayed the same (its files, sizes and times) for ``settle_s`` (the
    capture software has finished writing it). While the server cannot be reached, the scan stops and
    starts again at the next one; a folder the checks or the server refuse is reported once, and again
    only after it changes. A folder that changes after its upload is looked at again.
    """
    console, errors = Console(soft_wrap=True), Console(stderr=True, soft_wrap=True)
    transport = Transport(server, key, retry_for_s=max(interval_s, 30.0))
    uploader = Uploader(transport, verify_done=False)
    seen: dict[Path, tuple[tuple[tuple[str, int, int], ...], float]] = {}
    refused: dict[Path, tuple[tuple[str, int, int], ...]] = {}
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
                _report(console, errors, outcome)
                if outcome.retryable:
                    break  # the server is out of reach: the other folders would only wait for it too
                if outcome.error is not None:
                    refused[folder] = snapshot
            time.sleep(interval_s)
    except KeyboardInterrupt:
        console.print("stopped")
    finally:
        transport.close()
