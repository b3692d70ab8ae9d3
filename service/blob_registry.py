"""The object store's register of blobs (table ``stored_blobs``): how writers and the garbage collector
agree, through the database, on which blob may be deleted, where a folder has an atomic rename and an
object store has none.

- A writer *reserves* a blob before it writes the object: the row's ``committed_at`` becomes now. A blob
  reserved within the collector's grace period is never deleted, so the record that names it can follow.
- The collector *claims* a blob (``claimed_at`` = now) only if its row was not reserved since the grace
  period began, then deletes the object, then *forgets* the row.
- A writer that finds a live claim waits until the row is forgotten or the claim lapses (``claim_s``),
  then reserves it afresh and writes the object again: so its bytes are never written before a
  collector's delete of them.
- A collector that cannot delete within half the claim gives the claim up rather than delete late; a
  collector killed mid-claim leaves a claim that lapses by itself.

Each of these is one write transaction that locks the row (``SELECT ... FOR UPDATE`` on PostgreSQL; SQLite
has one writer at a time), and every time is the database's clock, so writers on many machines agree.
"""

from __future__ import annotations

import time
from datetime import UTC, datetime, timedelta

from sqlalchemy import select
from sqlalchemy.orm import Session

from service.database import Database, database_now
from service.models import StoredBlob
from service.storage import check_digest

__all__ = ["BlobRegistry"]


class BlobRegistry:
    """The rows of ``stored_blobs`` in ``database``; a collector's claim lasts ``claim_s`` seconds."""

    def __init__(self, database: Database, *, claim_s: float) -> None:
        self.database = database
        self.claim_s = claim_s

    def reserve(self, sha256: str, size_bytes: int) -> bool:
        """Mark the blob as committed now, before its object is written; waits while a collector holds a
        live claim on it (at most ``claim_s``). True when the reservation took over a lapsed claim: its
        collector's delete may still be on its way, so the object must be written again."""
        check_digest(sha256)
        pause_s = self.claim_s / 100
        while (taken := self.database.write(lambda s: self._reserve(s, sha256, size_bytes))) is None:
            time.sleep(pause_s)
        return taken

    def _reserve(self, session: Session, sha256: str, size_bytes: int) -> bool | None:
        """Reserved (True: over a lapsed claim), or None while a live claim holds."""
        now = database_now(session)
        row = session.get(StoredBlob, sha256, with_for_update=True)
        if row is None:
            session.add(StoredBlob(sha256=sha256, size_bytes=size_bytes, committed_at=now))
            session.flush()
            return False
        took_over = row.claimed_at is not None
        if row.claimed_at is not None and row.claimed_at > now - timedelta(seconds=self.claim_s):
            return None
        row.committed_at, row.claimed_at, row.size_bytes = now, None, size_bytes
        return took_over

    def claim(self, sha256: str, *, since: float) -> datetime | None:
        """Claim the blob for deletion unless it was reserved at or after ``since`` (epoch seconds) or
        another collector holds a live claim; the claim's time (its token), or None. A blob with no row
        (an object written by no writer of this database) gets one, claimed."""
        check_digest(sha256)
        return self.database.write(lambda session: self._claim(session, sha256, since=since))

    def _claim(self, session: Session, sha256: str, *, since: float) -> datetime | None:
        now = database_now(session)
        row = session.get(StoredBlob, sha256, with_for_update=True)
        if row is None:
            session.add(StoredBlob(sha256=sha256, size_bytes=0, committed_at=now, claimed_at=now))
            session.flush()
            return now
        if row.committed_at >= datetime.fromtimestamp(since, UTC):
            return None
        if row.claimed_at is not None and row.claimed_at > now - timedelta(seconds=self.claim_s):
            return None
        row.claimed_at = now
        return now

    def holds(self, sha256: str, claim: datetime) -> bool:
        """Whether the claim is still this collector's with half its time or more to run: a delete may go
        ahead now, long before any writer could take the blob over."""
        with self.database.reading() as session:
            row = session.get(StoredBlob, sha256)
            now = database_now(session)
        return (
            row is not None and row.claimed_at == claim and now < claim + timedelta(seconds=self.claim_s / 2)
        )

    def forget(self, sha256: str, claim: datetime) -> None:
        """Drop the row of a blob whose object was deleted under ``claim`` (unless a writer took it over)."""

        def drop(session: Session) -> None:
            row = session.get(StoredBlob, sha256, with_for_update=True)
            if row is not None and row.claimed_at == claim:
                session.delete(row)

        self.database.write(drop)

    def committed(self) -> dict[str, float]:
        """Every registered blob's last reservation time (epoch seconds)."""
        with self.database.reading() as session:
            rows = session.execute(select(StoredBlob.sha256, StoredBlob.committed_at))
            return {sha256: committed.timestamp() for sha256, committed in rows}
