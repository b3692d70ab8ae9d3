"""The embedded SQLite database, as several processes open it at once."""

from __future__ import annotations

import multiprocessing
from multiprocessing.queues import Queue
from multiprocessing.synchronize import Barrier
from pathlib import Path

from service.database import Database

PROCESSES = 8
TRIALS = 40
"""Eight processes connecting to a new file together, trial after trial: before the switch to WAL was
tried again, each of 4 runs of 50 trials had a failure; with it, none of 3 runs had one."""


def _open_and_write(url: str, barrier: Barrier, results: Queue) -> None:
    """Connect to the database when every process is ready, write to it, and report any error."""
    database = Database(url)
    barrier.wait()
    try:
        with database.write_engine.connect() as connection:
            connection.exec_driver_sql("CREATE TABLE IF NOT EXISTS opened (pid INTEGER)")
            connection.commit()
        results.put(None)
    except Exception as exc:  # the test reports it
        results.put(repr(exc))
    finally:
        database.dispose()


def test_processes_opening_a_new_database_at_once_all_open_it(tmp_path: Path) -> None:
    # An API and its workers started together (or `canopy db upgrade` run by several) each switch a new
    # file to WAL; SQLite refuses all but one at once, without waiting, unless the switch is tried again.
    forked = multiprocessing.get_context("fork")
    failures = []
    for trial in range(TRIALS):
        barrier, results = forked.Barrier(PROCESSES), forked.Queue()
        url = f"sqlite:///{tmp_path / f'canopy-{trial}.db'}"
        processes = [
            forked.Process(target=_open_and_write, args=(url, barrier, results)) for _ in range(PROCESSES)
        ]
        for process in processes:
            process.start()
        failures += [error for error in (results.get(timeout=60) for _ in processes) if error]
        for process in processes:
            process.join()
    assert failures == []
