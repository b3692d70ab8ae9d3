"""Durable, content-addressed storage of uploaded files and fused clouds, beside the database.

A blob is written to a temporary file (``.incoming-*`` in the store's folder) while its SHA-256 is taken,
flushed to disk, renamed into place under its digest and its folder flushed, so it is either whole or
absent after a crash. The database records a blob's digest only after the blob is durable; a crash between
the two leaves an unreferenced blob and never a record without its bytes; the garbage collector
(``service/blob_gc.py``) removes such blobs, and those of deleted captures. A crash while a file arrives
leaves its temporary file, which :meth:`BlobStore.remove_stale_incoming` clears.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import shutil
import tempfile
import time
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from types import TracebackType

__all__ = ["BlobStore", "IncomingBlob", "OutOfSpace", "sha256_hex"]

_INCOMING_PREFIX = ".incoming-"
_DOOMED_PREFIX = ".doomed-"


def sha256_hex(data: bytes) -> str:
    """The SHA-256 digest of ``data`` as 64 lowercase hex characters."""
    return hashlib.sha256(data).hexdigest()


class OutOfSpace(Exception):
    """The data disk has less free space than must stay free, or none at all: nothing was stored."""

    def __init__(self, free_bytes: int, floor_bytes: int, *, reason: str = "") -> None:
        super().__init__(
            f"{reason + ': ' if reason else ''}{free_bytes} bytes free on the data disk; "
            f"{floor_bytes} must stay free"
        )
        self.free_bytes = free_bytes
        self.floor_bytes = floor_bytes

    @classmethod
    def measured(cls, root: Path, floor_bytes: int, *, reason: str) -> OutOfSpace:
        """The error for a write the disk under ``root`` refused, with the space found there now."""
        return cls(shutil.disk_usage(root).free, floor_bytes, reason=reason)


@contextmanager
def _full_disk_is_out_of_space(root: Path, floor_bytes: int) -> Iterator[None]:
    """Turn the errors of a full disk or an exhausted quota into :class:`OutOfSpace`."""
    try:
        yield
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise OutOfSpace.measured(root, floor_bytes, reason=exc.strerror or "disk full") from exc
        raise


class IncomingBlob:
    """A blob being received: written to a temporary file as it comes, hashed on the way.

    Use as a context manager: :meth:`commit` makes it durable under its digest; leaving the block without
    committing (an error, a refused file) removes the temporary file.
    """

    def __init__(self, store: BlobStore) -> None:
        self._store = store
        with store.full_disk_is_out_of_space():
            descriptor, name = tempfile.mkstemp(dir=store.root, prefix=_INCOMING_PREFIX)
        self.path = Path(name)
        store.arriving.add(self.path)
        self._stream = os.fdopen(descriptor, "wb")
        self._hash = hashlib.sha256()
        self.size_bytes = 0

    def write(self, chunk: bytes) -> None:
        """Append ``chunk`` to the blob."""
        with self._store.full_disk_is_out_of_space():
            self._stream.write(chunk)
        self._hash.update(chunk)
        self.size_bytes += len(chunk)

    @property
    def sha256(self) -> str:
        """The digest of what was written so far."""
        return self._hash.hexdigest()

    def finish(self) -> None:
        """Flush everything written to the disk, so the file can be read and checked."""
        if not self._stream.closed:
            with self._store.full_disk_is_out_of_space():
                self._stream.flush()
                os.fsync(self._stream.fileno())
            self._stream.close()

    def commit(self) -> str:
        """Make the blob durable under its digest and return the digest; a no-op when the same bytes are
        stored already (another upload of them renamed its file into place first)."""
        self.finish()
        sha256 = self.sha256
        target = self._store.path(sha256)
        try:
            # The same bytes are stored already (another upload, or an earlier capture): mark them as just
            # committed, so the garbage collector leaves them alone while a record comes to name them
            # (see BlobStore.remove_unless_touched), and make sure their rename is durable.
            os.utime(target)
            if target.stat().st_size == self.size_bytes:
                _fsync_directory(target.parent)
                return sha256
        except FileNotFoundError:  # not stored, or taken away by the collector just now: store ours
            pass
        with self._store.full_disk_is_out_of_space():
            if not target.parent.is_dir():
                target.parent.mkdir(parents=True, exist_ok=True)
                _fsync_directory(self._store.root)
            os.replace(self.path, target)
            self._store.arriving.discard(self.path)
            _fsync_directory(target.parent)
        return sha256

    def __enter__(self) -> IncomingBlob:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        if not self._stream.closed:
            with contextlib.suppress(OSError):  # the buffer's rest could not be written: it is discarded
                self._stream.close()
        self.path.unlink(missing_ok=True)
        self._store.arriving.discard(self.path)


class BlobStore:
    """Blobs under ``root/<first two hex digits>/<sha-256 hex>``; identical bytes are stored once.

    ``min_free_bytes``: what must stay free on the disk; :meth:`check_space` refuses a write below it, so
    that the database beside the blobs always has room to commit.
    """

    def __init__(self, root: Path, *, min_free_bytes: int = 0) -> None:
        self.root = root
        self.min_free_bytes = min_free_bytes
        self.arriving: set[Path] = set()
        """The temporary files of this process's blobs still arriving."""

    def path(self, sha256: str) -> Path:
        """Where the blob with this digest lives (whether or not it exists)."""
        if len(sha256) != 64 or not all(c in "0123456789abcdef" for c in sha256):
            raise ValueError(f"not a SHA-256 hex digest: {sha256!r}")
        return self.root / sha256[:2] / sha256

    def full_disk_is_out_of_space(self) -> AbstractContextManager[None]:
        """A context in which a full disk's OSError becomes :class:`OutOfSpace`."""
        return _full_disk_is_out_of_space(self.root, self.min_free_bytes)

    def check_space(self, incoming_bytes: int = 0) -> None:
        """Raise :class:`OutOfSpace` unless ``incoming_bytes`` more leave ``min_free_bytes`` free."""
        free = shutil.disk_usage(self.root).free
        if free - incoming_bytes < self.min_free_bytes:
            raise OutOfSpace(free, self.min_free_bytes)

    def receive(self) -> IncomingBlob:
        """A new blob to write into (see :class:`IncomingBlob`)."""
        return IncomingBlob(self)

    def put(self, data: bytes) -> str:
        """Store ``data`` durably and return its digest; a no-op when the same bytes are stored already."""
        self.check_space(len(data))
        with self.receive() as incoming:
            incoming.write(data)
            return incoming.commit()

    def read(self, sha256: str) -> bytes:
        """The bytes of a stored blob; raises FileNotFoundError when it is absent."""
        return self.path(sha256).read_bytes()

    def stored(self) -> Iterator[tuple[str, float]]:
        """Every stored blob's digest and the time (epoch seconds) it was last committed."""
        for folder in sorted(self.root.glob("[0-9a-f][0-9a-f]")):
            for blob in folder.iterdir():
                if len(blob.name) != 64 or blob.name.startswith("."):
                    continue
                try:
                    committed = blob.stat().st_mtime
                except FileNotFoundError:  # removed meanwhile
                    continue
                yield blob.name, committed

    def remove_unless_touched(self, sha256: str, *, since: float) -> int | None:
        """Remove a blob unless it was committed at or after ``since`` (epoch seconds); the bytes freed, or
        None when it was kept (or is gone).

        The blob is first renamed aside and its time read again there: an upload of the same bytes marks
        the blob before its record is written, and does so either before the rename (the mark is seen
        and the blob is put back) or after it (the upload finds no blob and stores its own copy). A
        collector stopped between the two leaves the blob aside; :meth:`restore_set_aside` puts it back.
        """
        target = self.path(sha256)
        doomed = _doomed_path(target)
        try:
            os.replace(target, doomed)
        except FileNotFoundError:
            return None
        status = doomed.stat()
        if status.st_mtime >= since:
            os.replace(doomed, target)
            return None
        doomed.unlink()
        _fsync_directory(target.parent)
        return status.st_size

    def restore_set_aside(self) -> int:
        """Put back the blobs a stopped collector had set aside but not yet checked; how many."""
        restored = 0
        for doomed in self.root.glob(f"??/{_DOOMED_PREFIX}*"):
            target = doomed.with_name(doomed.name.removeprefix(_DOOMED_PREFIX))
            with contextlib.suppress(FileNotFoundError):
                os.replace(doomed, target)
                restored += 1
        return restored

    def discard_arriving(self) -> int:
        """Remove the temporary files of this process's uploads still arriving, how many: at shutdown, once
        the requests under way were cancelled (their blocks never ran to the end that removes them). Other
        processes' uploads into the same folder are left alone."""
        removed = 0
        for path in list(self.arriving):
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed += 1
            self.arriving.discard(path)
        return removed

    def remove_stale_incoming(self, *, older_than_s: float) -> int:
        """Remove the temporary files of uploads that ended without finishing (a killed server, a dropped
        connection mid-write) untouched for ``older_than_s``; a file still arriving is written to all the
        time and stays. Also clears those of older versions, which kept them beside the blobs. Returns how
        many were removed."""
        deadline = time.time() - older_than_s
        removed = 0
        for stale in [*self.root.glob(f"{_INCOMING_PREFIX}*"), *self.root.glob(f"??/{_INCOMING_PREFIX}*")]:
            try:
                if stale.stat().st_mtime < deadline:
                    stale.unlink()
                    removed += 1
            except FileNotFoundError:  # finished or removed meanwhile
                continue
        return removed


def _doomed_path(target: Path) -> Path:
    return target.with_name(f"{_DOOMED_PREFIX}{target.name}")


def _fsync_directory(path: Path) -> None:
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)
