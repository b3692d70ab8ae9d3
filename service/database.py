"""Database engines and sessions: SQLite by default, PostgreSQL by changing the URL.

SQLite connections get WAL (readers never wait for the writer), a busy timeout, foreign keys and full
synchronous commits (an acknowledged write survives power loss). Transactions that write start with
``BEGIN IMMEDIATE``, so two writers queue on the busy timeout instead of failing when a read lock cannot be
upgraded; reads stay deferred and never block the writer. Within one process, writers take turns on a
lock first: SQLite's busy handler polls with sleeps growing to 100 ms, so fifty requests writing at once
would each wait far longer than the writes take; the busy timeout is left to writers of other processes.
"""

from __future__ import annotations

import random
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext
from datetime import UTC, datetime
from typing import Any, TypeVar

from sqlalchemy import Engine, create_engine, event, func, select, text
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, sessionmaker

__all__ = ["Database", "database_now"]

_SQLITE_BUSY_TIMEOUT_MS = 10_000
"""How long a writer waits for another's transaction: write transactions hold no file I/O and last
milliseconds, and a worker's lease renewal (every lease/3 s) must land before the lease runs out."""
T = TypeVar("T")


def _to_wal(cursor: sqlite3.Cursor) -> None:
    """Put the database in WAL mode (a no-op once it is). Processes opening a new database file at once
    (an API and its workers started together, `canopy db upgrade` run by several) each switch it, and the
    switch needs the file to themselves: SQLite answers "database is locked" at once, without the busy
    timeout, to the one that would otherwise deadlock with another switching too. It is tried again, with
    short random pauses, until the busy timeout is spent."""
    deadline = time.monotonic() + _SQLITE_BUSY_TIMEOUT_MS / 1000
    while True:
        try:
            cursor.execute("PRAGMA journal_mode=WAL")
            return
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc) or time.monotonic() > deadline:
                raise
            time.sleep(random.uniform(0.005, 0.05))


def _sqlite_engine(url: str, *, begin: str) -> Engine:
    engine = create_engine(
        url, connect_args={"check_same_thread": False, "timeout": _SQLITE_BUSY_TIMEOUT_MS / 1000}
    )

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_connection: Any, _record: Any) -> None:
        # Let SQLAlchemy's begin event, not the driver, decide when and how a transaction starts.
        dbapi_connection.isolation_level = None
        cursor = dbapi_connection.cursor()
        _to_wal(cursor)
        for pragma in ("synchronous=FULL", "foreign_keys=ON", f"busy_timeout={_SQLITE_BUSY_TIMEOUT_MS}"):
            cursor.execute(f"PRAGMA {pragma}")
        cursor.close()

    @event.listens_for(engine, "begin")
    def _on_begin(connection: Any) -> None:
        connection.exec_driver_sql(begin)

    return engine


class Database:
    """The engines and session factories of one database URL.

    Use :meth:`reading` for queries and :meth:`writing` for anything that changes rows; ``writing`` commits
    when the block ends without an exception and rolls back otherwise.
    """

    def __init__(self, url: str) -> None:
        self.url = url
        self.is_sqlite = url.startswith("sqlite")
        if self.is_sqlite:
            self.read_engine = _sqlite_engine(url, begin="BEGIN")
            self.write_engine = _sqlite_engine(url, begin="BEGIN IMMEDIATE")
        else:
            self.read_engine = self.write_engine = create_engine(url, pool_pre_ping=True)
        self._read_sessions = sessionmaker(self.read_engine, expire_on_commit=False)
        self._write_sessions = sessionmaker(self.write_engine, expire_on_commit=False)
        # PostgreSQL takes concurrent writers itself, with row locks.
        self._turn: AbstractContextManager[Any] = threading.Lock() if self.is_sqlite else nullcontext()

    @contextmanager
    def reading(self) -> Iterator[Session]:
        """A session for queries; its transaction is rolled back at the end."""
        with self._read_sessions() as session:
            yield session

    @contextmanager
    def writing(self) -> Iterator[Session]:
        """A session whose transaction commits at the end of the block, or rolls back on an exception."""
        with self._turn, self._write_sessions() as session, session.begin():
            yield session

    def write(self, work: Callable[[Session], T]) -> T:
        """Run ``work`` in a write transaction, once more if a concurrent writer won a uniqueness race.

        Two requests creating the same orchard, or storing the same file, at the same instant: on
        PostgreSQL one of them violates a unique constraint; run again, it finds the other's row. (SQLite
        serialises writers, so there it never happens.)
        """
        try:
            with self.writing() as session:
                return work(session)
        except IntegrityError:
            with self.writing() as session:
                return work(session)

    def ping(self) -> None:
        """Raise unless the database answers a trivial query."""
        with self.read_engine.connect() as connection:
            connection.execute(text("SELECT 1"))

    def dispose(self) -> None:
        """Close every pooled connection (before a process exits or forks)."""
        self.read_engine.dispose()
        if self.write_engine is not self.read_engine:
            self.write_engine.dispose()


def database_now(session: Session) -> datetime:
    """The current time by the database's clock (PostgreSQL), or this machine's (SQLite), aware UTC."""
    if session.get_bind().dialect.name == "postgresql":
        now = session.scalar(select(func.clock_timestamp()))
        assert now is not None
        return now.astimezone(UTC)
    return datetime.now(UTC)
