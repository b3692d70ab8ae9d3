"""The measurement child's lifeline: it ends with its worker, however the worker ends."""

from __future__ import annotations

import multiprocessing
import time
from multiprocessing.connection import Connection

from worker.child import exit_with_worker


def _wait_forever(lifeline: Connection) -> None:
    exit_with_worker(lifeline)
    while True:
        time.sleep(1)


def test_child_exits_when_the_worker_end_of_its_lifeline_closes() -> None:
    processes = multiprocessing.get_context("forkserver")
    lifeline, held_end = processes.Pipe(duplex=False)
    child = processes.Process(target=_wait_forever, args=(lifeline,), daemon=True)
    child.start()
    lifeline.close()
    child.join(timeout=1.0)
    still_running = child.is_alive()
    held_end.close()  # what the kernel does for a worker killed with SIGKILL
    child.join(timeout=30)
    assert still_running
    assert child.exitcode == 70
