"""Backing up and restoring the embedded default: the SQLite database and the blobs it refers to.

A backup is taken while the service runs. The database is copied first, with SQLite's online backup (a
consistent snapshot, taken page by page while writers go on); then every blob that snapshot refers to (the
captures' files and the fused clouds) is copied and its SHA-256 checked. Blobs are made durable before any
record names them, so each one the snapshot names exists; blobs stored after the snapshot are not needed by
it. Blobs are never changed once stored, so a backup into a folder holding an earlier one copies only the
new blobs.

Layout of a backup folder: ``canopy.db``, ``blobs/<2 hex>/<sha-256>``, and ``backup.json`` (when, from
where, how many of each), the same layout as a data folder, so a restore is a copy back.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sqlite3
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

__all__ = ["BackupError", "BackupReport", "backup", "restore"]

_DATABASE = "canopy.db"
_BLOBS = "blobs"
_MANIFEST = "backup.json"
_CHUNK = 1024 * 1024


class BackupError(Exception):
    """A backup or restore that cannot be made as asked; the message says why and what to do."""


@dataclass(frozen=True)
class BackupReport:
    """What a backup holds (or a restore brought back)."""

    taken_at: str
    source: str
    captures: int
    files: int
    measurements: int
    blobs: int
    blobs_copied: int
    bytes_copied: int


def backup(data_dir: Path, destination: Path) -> BackupReport:
    """Copy the database of ``data_dir`` and the blobs it refers to into ``destination`` (created, or an
    earlier backup's folder, which is brought up to date)."""
    database = data_dir / _DATABASE
    if not database.is_file():
        raise BackupError(f"no Canopy database at {database}: nothing to back up")
    destination.mkdir(parents=True, exist_ok=True)
    taken_at = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    snapshot = destination / f".{_DATABASE}.partial"
    _copy_database(database, snapshot)
    digests, counts = _referenced_blobs(snapshot)
    copied, size = _copy_blobs(digests, data_dir / _BLOBS, destination / _BLOBS)
    os.replace(snapshot, destination / _DATABASE)  # the database last: a backup cut short holds the old one
    report = BackupReport(
        taken_at=taken_at,
        source=str(data_dir.resolve()),
        blobs=len(digests),
        blobs_copied=copied,
        bytes_copied=size,
        **counts,
    )
    (destination / _MANIFEST).write_text(json.dumps(asdict(report), indent=2) + "\n")
    return report


def restore(source: Path, data_dir: Path) -> BackupReport:
    """Bring the backup in ``source`` back into ``data_dir``, which must hold no database (stop the service
    and move the old data folder aside first); every blob is checked against its digest on the way."""
    database = source / _DATABASE
    if not database.is_file() or not (source / _MANIFEST).is_file():
        raise BackupError(f"{source} is not a Canopy backup (it has no {_DATABASE} and {_MANIFEST})")
    if any((data_dir / f"{_DATABASE}{suffix}").exists() for suffix in ("", "-wal", "-shm")):
        raise BackupError(
            f"{data_dir} holds a database already; stop the service, move that data folder aside, and "
            "restore into an empty one"
        )
    data_dir.mkdir(parents=True, exist_ok=True)
    digests, counts = _referenced_blobs(database)
    copied, size = _copy_blobs(digests, source / _BLOBS, data_dir / _BLOBS)
    partial = data_dir / f".{_DATABASE}.partial"
    _copy_database(database, partial)
    os.replace(partial, data_dir / _DATABASE)
    taken = json.loads((source / _MANIFEST).read_text())
    return BackupReport(
        taken_at=taken["taken_at"],
        source=str(source.resolve()),
        blobs=len(digests),
        blobs_copied=copied,
        bytes_copied=size,
        **counts,
    )


def _copy_database(source: Path, target: Path) -> None:
    """A consistent copy of a live SQLite database (the online backup API), flushed to disk."""
    target.unlink(missing_ok=True)
    with sqlite3.connect(source) as origin, sqlite3.connect(target) as copy:
        origin.backup(copy)
    with target.open("rb") as written:
        os.fsync(written.fileno())


def _referenced_blobs(database: Path) -> tuple[list[str], dict[str, int]]:
    """The digests of every blob ``database`` refers to, and its counts of captures, files, measurements."""
    with sqlite3.connect(database) as connection:
        files = [row[0] for row in connection.execute("SELECT sha256 FROM capture_files")]
        clouds = [row[0] for row in connection.execute("SELECT cloud_sha256 FROM measurements")]
        captures = connection.execute("SELECT COUNT(*) FROM captures").fetchone()[0]
    counts = {"captures": captures, "files": len(files), "measurements": len(clouds)}
    return sorted(set(files) | set(clouds)), counts


def _copy_blobs(digests: list[str], source: Path, target: Path) -> tuple[int, int]:
    """Copy the blobs ``target`` lacks, checking each one's SHA-256; how many were copied and their bytes."""
    copied = size = 0
    for digest in digests:
        destination = target / digest[:2] / digest
        if destination.is_file():
            continue
        origin = source / digest[:2] / digest
        if not origin.is_file():
            raise BackupError(f"blob {digest} that the database refers to is missing from {source}")
        destination.parent.mkdir(parents=True, exist_ok=True)
        partial = destination.with_name(f".{digest}.partial")
        hashed = hashlib.sha256()
        with origin.open("rb") as reading, partial.open("wb") as writing:
            while chunk := reading.read(_CHUNK):
                hashed.update(chunk)
                writing.write(chunk)
            writing.flush()
            os.fsync(writing.fileno())
        if hashed.hexdigest() != digest:
            partial.unlink()
            raise BackupError(
                f"blob {digest} in {source} does not hold the bytes of its digest: it is damaged"
            )
        shutil.copystat(origin, partial)
        os.replace(partial, destination)
        copied += 1
        size += destination.stat().st_size
    return copied, size
