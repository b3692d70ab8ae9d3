"""Durable, content-addressed storage of uploaded files and fused clouds, beside the database.

A blob is named by its SHA-256 and written to a temporary file, flushed to disk, renamed into place and its
folder flushed, so it is either whole or absent after a crash. The database records a blob's digest only
after the blob is durable; a crash between the two leaves an unreferenced blob and never a record without
its bytes.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

__all__ = ["BlobStore", "sha256_hex"]


def sha256_hex(data: bytes) -> str:
    """The SHA-256 digest of ``data`` as 64 lowercase hex characters."""
    return hashlib.sha256(data).hexdigest()


class BlobStore:
    """Blobs under ``root/<first two hex digits>/<sha-256 hex>``; identical bytes are stored once."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def path(self, sha256: str) -> Path:
        """Where the blob with this digest lives (whether or not it exists)."""
        if len(sha256) != 64 or not all(c in "0123456789abcdef" for c in sha256):
            raise ValueError(f"not a SHA-256 hex digest: {sha256!r}")
        return self.root / sha256[:2] / sha256

    def put(self, data: bytes) -> str:
        """Store ``data`` durably and return its digest; a no-op when the same bytes are stored already."""
        sha256 = sha256_hex(data)
        target = self.path(sha256)
        if target.is_file() and target.stat().st_size == len(data):
            # Another upload of the same bytes renamed it into place; make sure that rename is durable.
            _fsync_directory(target.parent)
            return sha256
        if not target.parent.is_dir():
            target.parent.mkdir(parents=True, exist_ok=True)
            _fsync_directory(self.root)
        descriptor, temporary = tempfile.mkstemp(dir=target.parent, prefix=".incoming-")
        try:
            with os.fdopen(descriptor, "wb") as stream:
                stream.write(data)
                stream.flush()
                os.fsync(stream.fileno())
            os.replace(temporary, target)
        except BaseException:
            Path(temporary).unlink(missing_ok=True)
            raise
        _fsync_directory(target.parent)
        return sha256

    def read(self, sha256: str) -> bytes:
        """The bytes of a stored blob; raises FileNotFoundError when it is absent."""
        return self.path(sha256).read_bytes()


def _fsync_directory(path: Path) -> None:
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)
