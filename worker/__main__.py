"""``python -m worker``: run one worker until SIGTERM or Ctrl-C (what ``canopy worker`` starts), or until
its stdin closes when started with ``--until-stdin-closes`` (what ``canopy up`` does)."""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
from types import FrameType

from service.context import Context
from service.migrate import is_current
from service.settings import SettingsError, load_settings
from worker.metrics import WorkerMetrics
from worker.runner import Worker

UNTIL_STDIN_CLOSES = "--until-stdin-closes"
"""Given by a parent that keeps the worker's stdin open while it lives (``canopy up``): when the parent
ends, however it ends, the worker hands its job back and stops instead of running on unsupervised."""


def _stop_when_stdin_closes(worker: Worker) -> None:
    # The file descriptor, not sys.stdin: a daemon thread blocked in a buffered read holds the buffer's
    # lock, and the interpreter's shutdown then dies on it ("Fatal Python error: _enter_buffered_busy").
    while os.read(sys.stdin.fileno(), 4096):
        pass
    worker.stop()


def main() -> None:
    """Run a worker on the database the ``CANOPY_*`` settings name."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        settings = load_settings(warn=UNTIL_STDIN_CLOSES not in sys.argv[1:])
    except SettingsError as exc:
        sys.stderr.write(f"error: {exc}\n")
        sys.exit(2)
    os.nice(settings.worker_nice)  # before the fork server starts: every measurement inherits it
    context = Context.from_settings(settings)
    if not is_current(context.database):
        sys.stderr.write(
            "error: the database is not initialised or not at the newest schema; start `canopy serve` "
            "(or `canopy up`) once to migrate it\n"
        )
        sys.exit(2)
    metrics = WorkerMetrics()
    if settings.worker_metrics_port is not None:
        metrics.serve(settings.worker_metrics_port)
    worker = Worker(context, metrics=metrics)

    def stop(_signal: int, _frame: FrameType | None) -> None:
        worker.stop()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    if UNTIL_STDIN_CLOSES in sys.argv[1:]:
        threading.Thread(target=_stop_when_stdin_closes, args=(worker,), daemon=True).start()
    worker.run_forever()
    context.database.dispose()


if __name__ == "__main__":
    main()
