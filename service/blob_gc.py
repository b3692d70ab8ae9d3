"""The blob garbage collector: removes stored blobs no record names (the files of deleted captures, a blob
whose record never came because its process died between the two), safely while uploads and workers run.

A blob is removed only when no capture file, fused cloud or figure names it and it was last committed
more than ``blob_gc_grace_s`` ago: whatever stores a blob commits it (or, when the same bytes are there
already, marks it) before writing the record that names it, and the grace covers that gap many times
over. The removal itself reads the mark again after setting the blob aside
(:meth:`BlobStore.remove_unless_touched`), so an upload of the same bytes at that very moment keeps them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from sqlalchemy import select
from sqlalchemy.orm import Session

from service.database import Database
from service.models import CaptureFile, Measurement
from service.storage import BlobStore

__all__ = ["Collection", "collect_garbage", "referenced_blobs"]


@dataclass(frozen=True)
class Collection:
    """What one run of the collector found and did."""

    blobs: int
    referenced: int
    recent: int
    removed: int
    bytes_freed: int
    restored: int


def referenced_blobs(session: Session) -> set[str]:
    """Every digest a record names: capture files, fused clouds, figures."""
    named = set(session.scalars(select(CaptureFile.sha256)))
    for cloud, figures in session.execute(select(Measurement.cloud_sha256, Measurement.figures)):
        named.add(cloud)
        named.update((figures or {}).values())
    return named


def collect_garbage(
    database: Database, store: BlobStore, *, grace_s: float, dry_run: bool = False
) -> Collection:
    """Remove the blobs no record names that were last committed more than ``grace_s`` ago (with
    ``dry_run``, only count them)."""
    restored = 0 if dry_run else store.restore_set_aside()
    since = time.time() - grace_s
    candidates = list(store.stored())
    with database.reading() as session:
        named = referenced_blobs(session)
    unnamed_old = [digest for digest, committed in candidates if digest not in named and committed < since]
    removed = freed = 0
    for digest in unnamed_old:
        if dry_run:
            removed += 1
            continue
        size = store.remove_unless_touched(digest, since=since)
        if size is not None:
            removed += 1
            freed += size
    referenced = sum(1 for digest, _ in candidates if digest in named)
    return Collection(
        blobs=len(candidates),
        referenced=referenced,
        recent=len(candidates) - referenced - len(unnamed_old),
        removed=removed,
        bytes_freed=freed,
        restored=restored,
    )
