"""The worker loop: claim a job, run its measurement in a child process, keep the lease alive while it
runs, and record the outcome only while still holding the lease.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import socket
import threading
import time
import uuid
from dataclasses import dataclass
from multiprocessing import forkserver
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import Any

from sqlalchemy import select
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session

from service.captures.service import get_capture
from service.context import Context
from service.jobs.queue import Lease, claim, complete, fail, release, renew
from service.models import CaptureFile
from service.storage import OutOfSpace
from worker.child import MeasurementSpec, nothing, run_measurement
from worker.metrics import WorkerMetrics

__all__ = ["Worker"]

log = logging.getLogger("canopy.worker")


_WAIT_S = 5.0
"""Pause before trying again when the database is unreachable or the data disk is full."""
_RECORD_TRIES = 3

_OUTCOME_LOG = {
    "ok": "succeeded",
    "error": "failed (the measurement explains why)",
    "crash": "crashed (retried while attempts remain)",
    "timeout": "timed out (retried while attempts remain)",
    "stopped": "handed back to the queue (worker stopping)",
    "no_space": "handed back to the queue (the data disk is full)",
    "store_unavailable": "handed back to the queue (the object store did not answer)",
    "lost": "abandoned (lease lost)",
}
_HANDED_BACK_TO_WAIT = ("no_space", "store_unavailable")
"""Outcomes of the storage, not of the job: the job goes back to the queue, its attempt not counted, and
the worker waits before it claims again."""


@dataclass(frozen=True)
class _Outcome:
    kind: str  # a key of _OUTCOME_LOG
    message: tuple[Any, ...] = ()


class Worker:
    """Runs jobs one after another until :meth:`stop` is called.

    Parameters
    ----------
    context
        The service's settings, database and blob store.
    name
        Names this worker in leases and logs; unique per process by default.
    metrics
        Where job durations are counted (a registry of its own by default).
    """

    def __init__(
        self, context: Context, *, name: str | None = None, metrics: WorkerMetrics | None = None
    ) -> None:
        self.context = context
        self.metrics = metrics or WorkerMetrics()
        self.owner = name or f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:6]}"
        self._stopping = threading.Event()
        # A fork server that has imported the measurement core starts each job's process in milliseconds,
        # without inheriting this process's database connections.
        self._processes = multiprocessing.get_context("forkserver")
        self._processes.set_forkserver_preload(["worker.child"])
        forkserver.ensure_running()  # now, so the first job does not wait for the imports
        # Its first process starts once the imports are done: a worker that says it waits for jobs can
        # start one at once, and one stopped at once leaves no fork server importing behind it.
        first = self._processes.Process(target=nothing, name="forkserver-ready")
        first.start()
        first.join()

    def stop(self) -> None:
        """Finish soon: a running job is handed back to the queue, and no new job is claimed."""
        self._stopping.set()

    def run_forever(self) -> None:
        """Claim and run jobs until stopped, waiting ``worker_poll_s`` whenever the queue is empty."""
        log.info("worker %s waiting for jobs", self.owner)
        while not self._stopping.is_set():
            try:
                ran = self.run_one()
            except OperationalError as exc:
                # The database went away (restart, network): a held job's lease runs out and it is claimed
                # again, so waiting and trying again loses nothing.
                log.warning("database unavailable (%s); trying again in %.0f s", exc.orig, _WAIT_S)
                self._stopping.wait(_WAIT_S)
                continue
            except OutOfSpace as full:
                # No job is claimed that could not store its cloud; the queue waits for the disk.
                log.warning("claiming no job: %s; trying again in %.0f s", full, _WAIT_S)
                self._stopping.wait(_WAIT_S)
                continue
            if not ran:
                self._stopping.wait(self.context.settings.worker_poll_s)

    def run_one(self) -> bool:
        """Claim and run one job; False when none was ready.

        Raises
        ------
        OutOfSpace
            The data disk has less free space than ``min_free_bytes``: no job is claimed.
        """
        settings = self.context.settings
        self.context.store.check_space()
        with self.context.database.writing() as session:
            lease = claim(
                session,
                owner=self.owner,
                lease_s=settings.job_lease_s,
                max_attempts=settings.job_max_attempts,
            )
        if lease is None:
            return False
        log.info("job %d: attempt %d started", lease.job_id, lease.attempt)
        started = time.monotonic()
        outcome = self._run(lease)
        self._record(lease, outcome)
        seconds = time.monotonic() - started
        self.metrics.attempt_seconds.labels(outcome.kind).observe(seconds)
        if outcome.kind == "ok":
            for stage, stage_seconds in outcome.message[0].get("timings_s", {}).items():
                self.metrics.stage_seconds.labels(stage).observe(stage_seconds)
        log.info("job %d: %s after %.2f s", lease.job_id, _OUTCOME_LOG[outcome.kind], seconds)
        if outcome.kind in _HANDED_BACK_TO_WAIT:
            log.warning("job %d: %s", lease.job_id, *outcome.message)
            self._stopping.wait(_WAIT_S)
        return True

    def _spec(self, lease: Lease) -> MeasurementSpec:
        with self.context.database.reading() as session:
            capture = get_capture(session, lease.capture_id)
            files = {
                record.path: record.sha256
                for record in session.scalars(
                    select(CaptureFile).where(CaptureFile.capture_id == lease.capture_id)
                )
            }
            return MeasurementSpec(
                job_id=lease.job_id,
                manifest=capture.manifest,
                files=files,
                settings=self.context.settings,
                overrides=lease.overrides,
                max_pixels=self.context.settings.max_image_pixels,
            )

    def _renew(self, lease: Lease, *, stage: str | None = None, progress: float | None = None) -> bool:
        """Extend the lease; False only when it is lost. A database hiccup is not a loss: the next
        heartbeat tries again, and if the lease runs out meanwhile, finishing checks it anyway."""
        try:
            with self.context.database.writing() as session:
                return renew(
                    session, lease, lease_s=self.context.settings.job_lease_s, stage=stage, progress=progress
                )
        except OperationalError as exc:
            log.warning(
                "job %d: could not renew the lease (%s); trying at the next heartbeat", lease.job_id, exc.orig
            )
            return True

    def _run(self, lease: Lease) -> _Outcome:
        receiver, sender = self._processes.Pipe(duplex=False)
        lifeline, held_end = self._processes.Pipe(duplex=False)
        process = self._processes.Process(
            target=run_measurement,
            args=(sender, lifeline, self._spec(lease)),
            name=f"canopy-job-{lease.job_id}",
            daemon=True,
        )
        process.start()
        sender.close()
        lifeline.close()
        log.info("job %d: measuring in process %s", lease.job_id, process.pid)
        try:
            return self._supervise(lease, process, receiver)
        finally:
            receiver.close()
            held_end.close()
            if process.is_alive():
                process.kill()
            process.join()

    def _supervise(self, lease: Lease, process: BaseProcess, receiver: Connection) -> _Outcome:
        settings = self.context.settings
        deadline = time.monotonic() + settings.job_timeout_s
        next_heartbeat = time.monotonic() + settings.job_heartbeat_s
        while True:
            # The child's messages first: an outcome that has arrived is never dropped for a shutdown.
            if receiver.poll(min(max(next_heartbeat - time.monotonic(), 0.0), 0.5)):
                try:
                    message = receiver.recv()
                except EOFError:
                    if self._stopping.is_set():
                        return _Outcome("stopped")
                    process.join(5)
                    return _Outcome("crash", (_exit_description(process.exitcode),))
                if message[0] != "progress":
                    return _Outcome(message[0], tuple(message[1:]))
                _, stage, fraction = message
                if not self._renew(lease, stage=stage, progress=fraction):
                    return _Outcome("lost")
                next_heartbeat = time.monotonic() + settings.job_heartbeat_s
            if self._stopping.is_set():
                return _Outcome("stopped")
            if time.monotonic() >= deadline:
                return _Outcome(
                    "timeout", (f"the measurement took longer than {settings.job_timeout_s:g} s",)
                )
            if time.monotonic() >= next_heartbeat:
                if not self._renew(lease):
                    return _Outcome("lost")
                next_heartbeat = time.monotonic() + settings.job_heartbeat_s

    def _record(self, lease: Lease, outcome: _Outcome) -> None:
        """Write the outcome, trying again through a short database outage: the result was paid for."""
        for attempt in range(_RECORD_TRIES):
            try:
                with self.context.database.writing() as session:
                    held = self._write_outcome(session, lease, outcome)
                break
            except OperationalError:
                if attempt == _RECORD_TRIES - 1:
                    raise
                self._stopping.wait(_WAIT_S)
        if not held:
            log.warning("job %d: lease lost to another worker; its outcome here is dropped", lease.job_id)

    def _write_outcome(self, session: Session, lease: Lease, outcome: _Outcome) -> bool:
        max_attempts = self.context.settings.job_max_attempts
        if outcome.kind == "ok":
            document, cloud_sha256, cloud_points, figures = outcome.message
            measurement_id = complete(
                session,
                lease,
                result=document,
                cloud_sha256=cloud_sha256,
                cloud_points=cloud_points,
                figures=figures,
            )
            return measurement_id is not None
        if outcome.kind == "error":
            return fail(session, lease, error=outcome.message[0], retry=False, max_attempts=max_attempts)
        if outcome.kind in ("crash", "timeout"):
            code = "measurement_crashed" if outcome.kind == "crash" else "measurement_timeout"
            error = {"code": code, "message": outcome.message[0]}
            return fail(session, lease, error=error, retry=True, max_attempts=max_attempts)
        if outcome.kind == "stopped" or outcome.kind in _HANDED_BACK_TO_WAIT:
            return release(session, lease)
        return False


def _exit_description(exitcode: int | None) -> str:
    if exitcode is not None and exitcode < 0:
        return f"the measurement process was killed by signal {-exitcode}" + (
            " (out of memory?)" if -exitcode == 9 else ""
        )
    return f"the measurement process ended with exit code {exitcode} before reporting a result"
