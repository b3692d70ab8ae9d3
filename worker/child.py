"""The measurement of one job, run in a child process so that a crash or an out-of-memory kill of the
measurement becomes an ordinary, retried failure of the job rather than the death of the worker.

The child reads the capture's files from the blob store, measures, stores the fused cloud and the report's
figures and sends its messages to the worker through a pipe: ``("progress", stage, fraction)`` while it
runs, then one of ``("ok", document, cloud_sha256, cloud_points, figures)`` (figures: name to SHA-256),
``("error", error_dict)`` for a failure the measurement core explains (permanent), ``("no_space", text)``
when the data disk had no room for the cloud or a figure and ``("store_unavailable", text)`` when the
object store did not answer (the job is handed back, not failed, in both), or
``("crash", text)`` for an unexpected exception (retried).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import threading
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

from canopy_core.capture import read_capture, stored_manifest
from canopy_core.cloud_io import ply_bytes
from canopy_core.errors import CanopyError
from canopy_core.measure import measure
from service.context import open_blob_store
from service.database import Database
from service.reports.figures import measurement_figures
from service.settings import Settings
from service.storage import ObjectStoreUnavailable, OutOfSpace

__all__ = ["MeasurementSpec", "exit_with_worker", "nothing", "run_measurement"]


@dataclass(frozen=True)
class MeasurementSpec:
    """Everything the child needs, picklable: the manifest, each file's blob digest, the settings."""

    job_id: int
    manifest: dict[str, Any]
    files: dict[str, str]
    settings: Settings
    overrides: dict[str, Any] | None
    max_pixels: int


def nothing() -> None:
    """Does nothing: the worker starts it first, to wait until the fork server has imported this module."""


def exit_with_worker(lifeline: Connection) -> None:
    """Exit as soon as the worker is gone, however it went (even SIGKILL, which it cannot act on).

    Only the worker holds the other end of ``lifeline`` and never writes to it: the read ends when the
    worker's end closes, with the worker. Then no orphan goes on measuring a job another worker will run.
    """

    def watch() -> None:
        with contextlib.suppress(EOFError, OSError):
            lifeline.recv()
        os._exit(70)

    threading.Thread(target=watch, name="lifeline", daemon=True).start()


def run_measurement(connection: Connection, lifeline: Connection, spec: MeasurementSpec) -> None:
    """Measure the job's capture and send the outcome through ``connection`` (see the module docstring).

    The worker decides when a measurement stops (its shutdown, a lost lease, a timeout): the child ignores
    the SIGINT and SIGTERM that a terminal or a service manager sends to the whole process group.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    exit_with_worker(lifeline)
    store = open_blob_store(spec.settings, Database(spec.settings.sqlalchemy_url))

    def read(path: str) -> bytes | None:
        digest = spec.files.get(path)
        return None if digest is None else store.read(digest)

    def progress(stage: str, fraction: float) -> None:
        connection.send(("progress", stage, fraction))

    try:
        progress("load", 0.0)
        capture = read_capture(stored_manifest(spec.manifest), read, max_pixels=spec.max_pixels, stored=True)
        result = measure(
            capture,
            overrides=spec.overrides,
            progress=progress,
            processes=spec.settings.worker_view_processes,
        )
        cloud_sha256 = store.put(ply_bytes(result.cloud))
        figures = {name: store.put(png) for name, png in measurement_figures(result, capture).items()}
        document = json.loads(result.to_json())
        connection.send(("ok", document, cloud_sha256, len(result.cloud), figures))
    except OutOfSpace as exc:
        connection.send(("no_space", str(exc)))
    except ObjectStoreUnavailable as exc:
        connection.send(("store_unavailable", str(exc)))
    except CanopyError as exc:
        connection.send(("error", exc.to_dict()))
    except Exception:
        connection.send(("crash", traceback.format_exc(limit=8)))
    finally:
        connection.close()
