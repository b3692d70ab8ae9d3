"""Durable, content-addressed storage of uploaded files and fused clouds: the interface every store has,
and the embedded default, a folder beside the database.

Whatever the store, a blob arrives in a temporary file (``.incoming-*`` in a local folder, the store's
spool) while its SHA-256 is taken, is flushed to disk and checked, and only then is kept under its digest,
whole or not at all. The database records a blob's digest only after the blob is kept; a crash between the
two leaves an unreferenced blob and never a record without its bytes; the garbage collector
(``service/blob_gc.py``) removes such blobs, and those of deleted captures. A crash while a file arrives
leaves its temporary file, which :meth:`BlobStore.remove_stale_incoming` clears.

:class:`FolderStore` keeps blobs in a folder, renaming each temporary file into place and flushing the
folder. The S3-compatible store is ``service/object_store.py``.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import shutil
import tempfile
import time
from abc import ABC, abstractmethod
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from types import TracebackType

__all__ = [
    "BlobStore",
    "FolderStore",
    "IncomingBlob",
    "ObjectStoreUnavailable",
    "OutOfSpace",
    "check_digest",
    "sha256_hex",
]

_INCOMING_PREFIX = ".incoming-"
_DOOMED_PREFIX = ".doomed-"


def sha256_hex(data: bytes) -> str:
    """The SHA-256 digest of ``data`` as 64 lowercase hex characters."""
    return hashlib.sha256(data).hexdigest()


def check_digest(sha256: str) -> str:
    """``sha256`` itself when it is 64 lowercase hex characters; ValueError otherwise (a blob's name goes into
    a path or an object key, so nothing else may pass)."""
    if len(sha256) != 64 or not all(c in "0123456789abcdef" for c in sha256):
        raise ValueError(f"not a SHA-256 hex digest: {sha256!r}")
    return sha256


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


class ObjectStoreUnavailable(Exception):
    """The object store did not answer, or refused a request: nothing was stored."""


class IncomingBlob:
    """A blob being received: written to a temporary file in the store's spool as it comes, hashed on the way.

    Use as a context manager: :meth:`commit` makes it durable under its digest; leaving the block removes
    the temporary file (if the store did not take it).
    """

    def __init__(self, store: BlobStore) -> None:
        self._store = store
        with store.full_disk_is_out_of_space():
            descriptor, name = tempfile.mkstemp(dir=store.spool_dir, prefix=_INCOMING_PREFIX)
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
        stored already."""
        self.finish()
        self._store.keep(self)
        return self.sha256

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


class BlobStore(ABC):
    """Where blobs are kept, by their SHA-256; identical bytes are kept once.

    Incoming blobs are written to ``spool_dir``, a folder on this machine's disk. ``min_free_bytes``: what
    must stay free on that disk; :meth:`check_space` refuses a write below it, so that the database beside
    it always has room to commit.
    """

    def __init__(self, spool_dir: Path, *, min_free_bytes: int = 0) -> None:
        self.spool_dir = spool_dir
        self.min_free_bytes = min_free_bytes
        self.arriving: set[Path] = set()
        """The temporary files of this process's blobs still arriving."""

    @abstractmethod
    def keep(self, incoming: IncomingBlob) -> None:
        """Make a finished incoming blob durable under its digest (its bytes may be stored already).

        Whoever commits the same bytes again marks the kept blob as just committed, before the record that
        names it is written: the garbage collector leaves a blob so marked alone for its grace period."""

    @abstractmethod
    def read(self, sha256: str) -> bytes:
        """The bytes of a stored blob; raises FileNotFoundError when it is absent."""

    @abstractmethod
    def file_path(self, sha256: str) -> Path | None:
        """A file on this machine's disk that holds the blob, when the store keeps its blobs in files
        (a web server can send it as it is); None otherwise, or when it is absent."""

    @abstractmethod
    def stored(self) -> Iterator[tuple[str, float]]:
        """Every stored blob's digest and the time (epoch seconds) it was last committed."""

    @abstractmethod
    def remove_unless_touched(self, sha256: str, *, since: float) -> int | None:
        """Remove a blob unless it was committed at or after ``since`` (epoch seconds), even by a commit
        running at this very moment; the bytes freed, or None when it was kept (or is gone)."""

    @abstractmethod
    def restore_set_aside(self) -> int:
        """Undo what a collector stopped in the middle of a removal left half done; how many blobs."""

    @abstractmethod
    def ping(self) -> None:
        """Raise unless blobs can be stored now (for the readiness check)."""

    def full_disk_is_out_of_space(self) -> AbstractContextManager[None]:
        """A context in which a full disk's OSError becomes :class:`OutOfSpace`."""
        return _full_disk_is_out_of_space(self.spool_dir, self.min_free_bytes)

    def check_space(self, incoming_bytes: int = 0) -> None:
        """Raise :class:`OutOfSpace` unless ``incoming_bytes`` more leave ``min_free_bytes`` free."""
        free = shutil.disk_usage(self.spool_dir).free
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
        spool = self.spool_dir
        for stale in [*spool.glob(f"{_INCOMING_PREFIX}*"), *spool.glob(f"??/{_INCOMING_PREFIX}*")]:
            try:
                if stale.stat().st_mtime < deadline:
                    stale.unlink()
                    removed += 1
            except FileNotFoundError:  # finished or removed meanwhile
                continue
        return removed


class FolderStore(BlobStore):
    """Blobs under ``root/<first two hex digits>/<sha-256 hex>``, the folder also the spool.

    A blob is renamed into place from its temporary file and the folder flushed, so it is whole or absent
    after a crash; its file's modification time is when it was last committed.
    """

    def __init__(self, root: Path, *, min_free_bytes: int = 0) -> None:
        super().__init__(root, min_free_bytes=min_free_bytes)
        self.root = root

    def path(self, sha256: str) -> Path:
        """Where the blob with this digest lives (whether or not it exists)."""
        check_digest(sha256)
        return self.root / sha256[:2] / sha256

    def keep(self, incoming: IncomingBlob) -> None:
        """Rename the incoming file into place, or, when the same bytes are there, renew their time."""
        target = self.path(incoming.sha256)
        try:
            # The same bytes are stored already (another upload, or an earlier capture): mark them as just
            # committed, so the garbage collector leaves them alone while a record comes to name them
            # (see remove_unless_touched), and make sure their rename is durable.
            os.utime(target)
            if target.stat().st_size == incoming.size_bytes:
                _fsync_directory(target.parent)
                return
        except FileNotFoundError:  # not stored, or taken away by the collector just now: store ours
            pass
        with self.full_disk_is_out_of_space():
            if not target.parent.is_dir():
                target.parent.mkdir(parents=True, exist_ok=True)
                _fsync_directory(self.root)
            os.replace(incoming.path, target)
            self.arriving.discard(incoming.path)
            _fsync_directory(target.parent)

    def read(self, sha256: str) -> bytes:
        return self.path(sha256).read_bytes()

    def file_path(self, sha256: str) -> Path | None:
        path = self.path(sha256)
        return path if path.is_file() else None

    def ping(self) -> None:
        if not os.access(self.root, os.W_OK | os.X_OK):
            raise PermissionError(f"the blob folder {self.root} is missing or not writable")

    def stored(self) -> Iterator[tuple[str, float]]:
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
        """The blob is first renamed aside and its time read again there: an upload of the same bytes marks
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
        """Put back the blobs a stopped collector had set aside but not yet checked."""
        restored = 0
        for doomed in self.root.glob(f"??/{_DOOMED_PREFIX}*"):
            target = doomed.with_name(doomed.name.removeprefix(_DOOMED_PREFIX))
            with contextlib.suppress(FileNotFoundError):
                os.replace(doomed, target)
                restored += 1
        return restored


def _doomed_path(target: Path) -> Path:
    return target.with_name(f"{_DOOMED_PREFIX}{target.name}")


def _fsync_directory(path: Path) -> None:
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)
