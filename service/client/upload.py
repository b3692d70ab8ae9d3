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
from pathlib import Path
from typing import Any

from canopy_core.capture import capture_time, load_capture, parse_manifest
from canopy_core.errors import CaptureError
from service.client.receipts import RECEIPT_NAME, Receipt
from service.client.transport import RequestRefused, ServerUnreachable, Transport

__all__ = [
    "UPLOADED_NAMES",
    "UploadOutcome",
    "Uploader",
    "capture_files",
    "find_captures",
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


def capture_files(folder: Path) -> dict[str, Path]:
    """The files of a capture folder to send, by their path inside it (``views/1/depth.png``)."""
    return {
        path.relative_to(folder).as_posix(): path
        for path in sorted(folder.glob("views/*/*"))
        if path.name in UPLOADED_NAMES and path.is_file()
    }


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


class Uploader:
    """Uploads capture folders to one server.

    Parameters
    ----------
    transport
        The retrying HTTP client of the server.
    """

    def __init__(self, transport: Transport) -> None:
        self.transport = transport

    def upload(self, folder: Path, *, on_bytes: Callable[[int], None] | None = None) -> UploadOutcome:
        """Check and send one capture folder; the outcome says what happened, never raises for the capture.

        ``on_bytes`` is called with each file's size as the server acknowledges it (for progress bars).
        """
        outcome = UploadOutcome(folder=folder)
        receipt = Receipt.load(folder)
        mine = receipt.for_server(self.transport.server)
        try:
            manifest = parse_manifest((folder / "capture.json").read_bytes())
            outcome.tree = f"{manifest.orchard} / {manifest.row} / {manifest.tree}"
            if mine.job_id is not None:
                # Everything was acknowledged, the job included: nothing to check or ask again.
                outcome.capture_id, outcome.job_id = mine.capture_id, mine.job_id
                outcome.files_already_there = len(mine.files)
                return outcome
            capture_time(load_capture(folder).manifest)
        except CaptureError as exc:
            outcome.error = f"not sent, the capture is invalid: {exc}"
            return outcome
        except OSError as exc:
            outcome.error = f"not sent, capture.json cannot be read: {exc}"
            return outcome
        step = "capture.json"
        try:
            created = self.transport.request(
                "POST", "/v1/captures", content=(folder / "capture.json").read_bytes()
            )
            outcome.capture_id = mine.capture_id = int(created.json()["id"])
            receipt.save(folder)
            status = self.transport.request("GET", f"/v1/captures/{mine.capture_id}").json()
            held = set(status["files_received"])
            for path, file in capture_files(folder).items():
                if path in held:
                    outcome.files_already_there += 1
                    continue
                step = path
                data = file.read_bytes()
                sha256, digest_header = _content_digest(data)
                self.transport.request(
                    "PUT",
                    f"/v1/captures/{mine.capture_id}/files/{path}",
                    content=data,
                    headers={"Content-Digest": digest_header},
                )
                mine.files[path] = sha256
                receipt.save(folder)
                outcome.files_sent += 1
                outcome.bytes_sent += len(data)
                if on_bytes is not None:
                    on_bytes(len(data))
            step = "the measurement job"
            job = self.transport.request(
                "POST",
                f"/v1/captures/{mine.capture_id}/jobs",
                headers={"Idempotency-Key": f"canopy-upload-{mine.capture_id}"},
            )
            outcome.job_id = mine.job_id = int(job.json()["id"])
            receipt.save(folder)
        except RequestRefused as exc:
            outcome.error = f"{step}: refused by the server: {exc}"
        except ServerUnreachable as exc:
            outcome.error, outcome.retryable = f"{step}: {exc}", True
        except OSError as exc:
            outcome.error = f"{step}: cannot read it: {exc}"
        return outcome


def wait_for_jobs(
    transport: Transport, outcomes: list[UploadOutcome], *, poll_s: float = 1.0
) -> Iterator[UploadOutcome]:
    """Yield each outcome with a job as its job finishes, its ``result`` holding the job (and measurement)."""
    pending = [outcome for outcome in outcomes if outcome.job_id is not None]
    while pending:
        still = []
        for outcome in pending:
            job = transport.request("GET", f"/v1/jobs/{outcome.job_id}").json()
            if job["state"] not in ("succeeded", "failed"):
                still.append(outcome)
                continue
            outcome.result = {"job": job}
            if job["state"] == "succeeded":
                try:
                    measurement = transport.request("GET", f"/v1/measurements/{job['measurement_id']}")
                    outcome.result["measurement"] = measurement.json()
                except RequestRefused as exc:
                    outcome.result["refused"] = str(exc)
            yield outcome
        pending = still
        if pending:
            transport.sleep(poll_s)


def receipt_complete(folder: Path, server: str) -> bool:
    """True when the folder's receipt says the server has the whole capture and its job."""
    if not (folder / RECEIPT_NAME).is_file():
        return False
    return Receipt.load(folder).for_server(server.rstrip("/")).job_id is not None
