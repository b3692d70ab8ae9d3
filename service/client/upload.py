"""Sending capture folders to the service: check locally, then send only what the server lacks.

For each capture: the same checks as the service (the core's ``load_capture`` and the capture time)
before any byte is sent; then create the capture (idempotent by tree and time), ask the server which
files it holds, send the others with their SHA-256, and start the measurement job under an Idempotency-Key
of the capture, so that however often an upload is repeated or resumed, the server holds one capture, each
file once, and one job. The receipt in the folder records each acknowledgement as it comes.
"""

from __future__ import annotations

import base64
import hashlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from canopy_core.capture import CaptureManifest, capture_time, load_capture, parse_manifest
from canopy_core.errors import CaptureError
from service.client.receipts import RECEIPT_NAME, Receipt, ServerReceipt
from service.client.transport import RequestRefused, ServerUnreachable, Transport

__all__ = [
    "UPLOADED_NAMES",
    "UploadOutcome",
    "Uploader",
    "capture_files",
    "files_to_send",
    "find_captures",
    "fingerprint",
    "finished_jobs",
    "receipt_complete",
    "wait_for_jobs",
]

UPLOADED_NAMES = ("camera.json", "depth.png", "color.png", "color.jpg")
"""The files of a view that are sent; capture.json is the capture's creation; ground_truth.json stays."""


def find_captures(root: Path) -> list[Path]:
    """Every capture folder (one holding capture.json) at or under ``root``, in path order."""
    if (root / "capture.json").is_file():
        return [root]
    return sorted(path.parent for path in root.rglob("capture.json") if path.is_file())


def capture_files(folder: Path, views: list[str]) -> dict[str, Path]:
    """The files of the capture's ``views`` to send, by their path inside it (``views/1/depth.png``).

    Only the views capture.json lists: a discarded take left in ``views/`` is not the capture's.
    """
    return {
        f"{view}/{name}": folder / view / name
        for view in views
        for name in UPLOADED_NAMES
        if (folder / view / name).is_file()
    }


def files_to_send(folder: Path) -> dict[str, Path]:
    """:func:`capture_files` of the views the folder's capture.json lists (none when it is unreadable)."""
    try:
        return capture_files(folder, parse_manifest((folder / "capture.json").read_bytes()).views)
    except (CaptureError, OSError):
        return {}


def fingerprint(folder: Path, files: dict[str, Path]) -> str:
    """What the capture folder holds now: capture.json's bytes and each file's path, size and time.

    Stored with the job in the receipt: a folder that changed after its upload is looked at again.
    """
    digest = hashlib.sha256((folder / "capture.json").read_bytes())
    for path, file in sorted(files.items()):
        status = file.stat()
        digest.update(f"\0{path}\0{status.st_size}\0{status.st_mtime_ns}".encode())
    return digest.hexdigest()


def _content_digest(data: bytes) -> tuple[str, str]:
    digest = hashlib.sha256(data)
    return digest.hexdigest(), f"sha-256=:{base64.b64encode(digest.digest()).decode()}:"


@dataclass
class UploadOutcome:
    """What became of one capture folder."""

    folder: Path
    tree: str = ""
    capture_id: int | None = None
    job_id: int | None = None
    files_sent: int = 0
    files_already_there: int = 0
    bytes_sent: int = 0
    error: str | None = None
    retryable: bool = False
    """True when the server was unreachable: trying again later may succeed; False for a refusal."""
    result: dict[str, Any] = field(default_factory=dict)


_DIGEST_RESENDS = 3
"""A file whose bytes arrive damaged (400 digest_mismatch) is sent again this many times at most."""


class FileChanged(Exception):
    """A file of the folder differs from the one the server holds under its path."""


def _check_same(file: Path, server_sha256: str, *, capture_id: int) -> None:
    """Raise :class:`FileChanged` unless ``file`` has the bytes the server holds (their SHA-256).

    A re-shot or edited file sent again must not be reported as already there: the measurement would be of
    the old one. The server keeps a capture's files unchanged (it refuses other bytes under a path), so the
    crew must record the new ones as a new capture, or delete the old capture first.
    """
    local = hashlib.sha256(file.read_bytes()).hexdigest()
    if local != server_sha256:
        raise FileChanged(
            f"changed since it was sent to capture {capture_id}: the server holds other bytes (sha-256 "
            f"{server_sha256[:12]}…, this file {local[:12]}…). To measure the new file, give the capture a "
            f"new captured_at in capture.json (a new capture), or delete capture {capture_id} with an admin "
            f"key (DELETE /v1/captures/{capture_id}) and upload again"
        )


class Uploader:
    """Uploads capture folders to one server.

    Parameters
    ----------
    transport
        The retrying HTTP client of the server.
    verify_done
        Before skipping a capture whose receipt says it is done, ask the server that it still has it (one
        request; a server that lost it, or was replaced, gets the capture again). ``watch`` trusts the
        receipt to stay quiet between scans.
    """

    def __init__(self, transport: Transport, *, verify_done: bool = True) -> None:
        self.transport = transport
        self.verify_done = verify_done

    def upload(self, folder: Path, *, on_bytes: Callable[[int], None] | None = None) -> UploadOutcome:
        """Check and send one capture folder; the outcome says what happened, never raises for the capture.

        ``on_bytes`` is called with each file's size as the server acknowledges it (for progress bars).
        """
        outcome = UploadOutcome(folder=folder)
        step = "capture.json"
        try:
            receipt = Receipt.load(folder)
            mine = receipt.for_server(self.transport.server)
            manifest = parse_manifest((folder / "capture.json").read_bytes())
            outcome.tree = f"{manifest.orchard} / {manifest.row} / {manifest.tree}"
            files = capture_files(folder, manifest.views)
            now = fingerprint(folder, files)
            done = mine.job_id is not None and mine.fingerprint == now
            if done and self._still_there(mine.capture_id, manifest):
                outcome.capture_id, outcome.job_id = mine.capture_id, mine.job_id
                outcome.files_already_there = len(files)
                return outcome
            capture_time(load_capture(folder).manifest)
            capture_json = (folder / "capture.json").read_bytes()
            created = self.transport.request("POST", "/v1/captures", content=capture_json)
            if created.json()["id"] != mine.capture_id:
                # A capture new to this server (or a server that lost it): nothing of the receipt holds.
                receipt.servers[self.transport.server] = mine = ServerReceipt()
            outcome.capture_id = mine.capture_id = int(created.json()["id"])
            receipt.save(folder)
            status = self.transport.request("GET", f"/v1/captures/{mine.capture_id}").json()
            held: dict[str, str] = status["files_sha256"]
            for path, file in files.items():
                if path in held:
                    step = path
                    _check_same(file, held[path], capture_id=mine.capture_id)
                    outcome.files_already_there += 1
                    continue
                step = path
                size = self._send(mine.capture_id, path, file)
                mine.files[path] = hashlib.sha256(file.read_bytes()).hexdigest()
                receipt.save(folder)
                outcome.files_sent += 1
                outcome.bytes_sent += size
                if on_bytes is not None:
                    on_bytes(size)
            step = "the measurement job"
            job = self.transport.request(
                "POST",
                f"/v1/captures/{mine.capture_id}/jobs",
                headers={"Idempotency-Key": f"canopy-upload-{mine.capture_id}"},
            )
            outcome.job_id = mine.job_id = int(job.json()["id"])
            mine.fingerprint = now
            receipt.save(folder)
        except CaptureError as exc:
            outcome.error = f"not sent, the capture is invalid: {exc}"
        except FileChanged as exc:
            outcome.error = f"{step}: {exc}"
        except RequestRefused as exc:
            outcome.error = f"{step}: refused by the server: {exc}"
        except ServerUnreachable as exc:
            outcome.error, outcome.retryable = f"{step}: {exc}", True
        except OSError as exc:
            outcome.error = f"{step}: cannot read the file or write the receipt: {exc}"
        except (ValueError, KeyError, TypeError) as exc:
            outcome.error = f"{step}: the server's answer is not the Canopy API's ({exc!r}); check --server"
        return outcome

    def _still_there(self, capture_id: int | None, manifest: CaptureManifest) -> bool:
        """True when the server still holds this capture under the id the receipt has (a server that was
        reset may have given that id to another capture, or to none)."""
        if not self.verify_done:
            return True
        try:
            held = self.transport.request("GET", f"/v1/captures/{capture_id}").json()
        except RequestRefused as exc:
            if exc.status == 404:
                return False
            raise
        same_tree = (held["orchard"], held["row"], held["tree"]) == (
            manifest.orchard,
            manifest.row,
            manifest.tree,
        )
        return same_tree and datetime.fromisoformat(held["captured_at"]) == capture_time(manifest)

    def _send(self, capture_id: int, path: str, file: Path) -> int:
        """PUT one file with its digest; a copy damaged on the way is sent again. Returns its size."""
        for attempt in range(_DIGEST_RESENDS + 1):
            data = file.read_bytes()
            _sha256, digest_header = _content_digest(data)
            try:
                self.transport.request(
                    "PUT",
                    f"/v1/captures/{capture_id}/files/{path}",
                    content=data,
                    headers={"Content-Digest": digest_header},
                )
                return len(data)
            except RequestRefused as exc:
                if exc.problem.get("code") != "digest_mismatch" or attempt == _DIGEST_RESENDS:
                    raise
        raise AssertionError("unreachable")


def finished_jobs(
    transport: Transport, outcomes: list[UploadOutcome]
) -> tuple[list[UploadOutcome], list[UploadOutcome]]:
    """Ask once for each outcome's job: those finished (their ``result`` holding the job, and its
    measurement when it succeeded) and those still waiting or running."""
    finished, running = [], []
    for outcome in outcomes:
        job = transport.request("GET", f"/v1/jobs/{outcome.job_id}").json()
        if job["state"] not in ("succeeded", "failed"):
            running.append(outcome)
            continue
        outcome.result = {"job": job}
        if job["state"] == "succeeded":
            try:
                measurement = transport.request("GET", f"/v1/measurements/{job['measurement_id']}")
                outcome.result["measurement"] = measurement.json()
            except RequestRefused as exc:
                outcome.result["refused"] = str(exc)
        finished.append(outcome)
    return finished, running


def wait_for_jobs(
    transport: Transport, outcomes: list[UploadOutcome], *, poll_s: float = 1.0
) -> Iterator[UploadOutcome]:
    """Yield each outcome with a job as its job finishes, its ``result`` holding the job (and measurement)."""
    pending = [outcome for outcome in outcomes if outcome.job_id is not None]
    while pending:
        finished, pending = finished_jobs(transport, pending)
        yield from finished
        if pending:
            transport.sleep(poll_s)


def receipt_complete(folder: Path, server: str) -> bool:
    """True when the folder's receipt says the server has the whole capture and its job, and the folder
    has not changed since."""
    if not (folder / RECEIPT_NAME).is_file():
        return False
    mine = Receipt.load(folder).for_server(server.rstrip("/"))
    if mine.job_id is None:
        return False
    try:
        manifest = parse_manifest((folder / "capture.json").read_bytes())
        return mine.fingerprint == fingerprint(folder, capture_files(folder, manifest.views))
    except (CaptureError, OSError):
        return False
