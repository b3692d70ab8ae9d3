"""Blobs in an S3-compatible object store (AWS S3, MinIO, Ceph, ...), for services whose API and workers run
on many machines: each blob is the object ``<prefix><first two hex digits>/<sha-256 hex>``.

An incoming blob is spooled and checked on this machine's disk as with the folder store, then written with
one PUT that carries its SHA-256, so the store itself refuses damaged bytes and an object is whole or
absent. Which blobs the garbage collector may delete is agreed through the database
(``service/blob_registry.py``), since an object store has no rename to set a blob aside with.

Credentials and region come from the environment the way every AWS SDK reads them (``AWS_ACCESS_KEY_ID``,
``AWS_SECRET_ACCESS_KEY``, ``AWS_REGION``, an instance role, ...).
"""

from __future__ import annotations

import base64
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

import boto3
from botocore.config import Config
from botocore.exceptions import BotoCoreError, ClientError

from service.blob_registry import BlobRegistry
from service.storage import BlobStore, IncomingBlob, check_digest

if TYPE_CHECKING:
    from mypy_boto3_s3 import S3Client

__all__ = ["ObjectStore", "ObjectStoreUnavailable", "s3_client"]

_MISSING = ("404", "NoSuchKey", "NotFound")


class ObjectStoreUnavailable(Exception):
    """The object store did not answer, or refused a request: nothing was stored."""


def s3_client(endpoint_url: str | None, *, attempts: int) -> S3Client:
    """A client for the S3 API at ``endpoint_url`` (None: AWS itself), retrying ``attempts`` times."""
    config = Config(retries={"max_attempts": attempts, "mode": "standard"})
    return boto3.client("s3", endpoint_url=endpoint_url, config=config)


class ObjectStore(BlobStore):
    """Blobs in ``bucket`` under ``prefix``; incoming ones spooled in ``spool_dir`` (see the module)."""

    def __init__(
        self,
        client: S3Client,
        bucket: str,
        *,
        prefix: str,
        registry: BlobRegistry,
        spool_dir: Path,
        min_free_bytes: int = 0,
    ) -> None:
        super().__init__(spool_dir, min_free_bytes=min_free_bytes)
        self.client = client
        self.bucket = bucket
        self.prefix = prefix
        self.registry = registry

    def key(self, sha256: str) -> str:
        """The object key of the blob with this digest."""
        check_digest(sha256)
        return f"{self.prefix}{sha256[:2]}/{sha256}"

    def keep(self, incoming: IncomingBlob) -> None:
        """Reserve the blob, then write it unless an object of its size is there already."""
        sha256 = incoming.sha256
        self.registry.reserve(sha256, incoming.size_bytes)
        if self._size(sha256) == incoming.size_bytes:
            return
        checksum = base64.b64encode(bytes.fromhex(sha256)).decode()
        with self._answering(f"storing blob {sha256}"), incoming.path.open("rb") as body:
            self.client.put_object(
                Bucket=self.bucket,
                Key=self.key(sha256),
                Body=body,
                ContentLength=incoming.size_bytes,
                ChecksumSHA256=checksum,
            )

    def read(self, sha256: str) -> bytes:
        with self._answering(f"reading blob {sha256}"):
            try:
                answer = self.client.get_object(Bucket=self.bucket, Key=self.key(sha256))
            except ClientError as exc:
                if _error_code(exc) in _MISSING:
                    raise FileNotFoundError(f"blob {sha256} is not in bucket {self.bucket}") from exc
                raise
            return answer["Body"].read()

    def file_path(self, sha256: str) -> Path | None:
        return None

    def stored(self) -> Iterator[tuple[str, float]]:
        """Every object under the prefix, and every registered blob whose object may be on its way; the
        later of the object's time and its last reservation."""
        committed = self.registry.committed()
        seen: set[str] = set()
        with self._answering("listing the blobs"):
            pages = self.client.get_paginator("list_objects_v2").paginate(
                Bucket=self.bucket, Prefix=self.prefix
            )
            for page in pages:
                for entry in page.get("Contents", []):
                    sha256 = entry["Key"].rsplit("/", 1)[-1]
                    if len(sha256) != 64:
                        continue
                    seen.add(sha256)
                    yield sha256, max(entry["LastModified"].timestamp(), committed.get(sha256, 0.0))
        for sha256, time_s in committed.items():
            if sha256 not in seen:
                yield sha256, time_s

    def remove_unless_touched(self, sha256: str, *, since: float) -> int | None:
        """Claim the blob in the register, delete its object while the claim holds, then forget it (see
        ``service/blob_registry.py``)."""
        claim = self.registry.claim(sha256, since=since)
        if claim is None:
            return None
        size = self._size(sha256)
        if size is not None:
            if not self.registry.holds(sha256, claim):
                return None  # too slow: a writer may take the blob over any moment; the claim lapses
            with self._answering(f"deleting blob {sha256}"):
                self.client.delete_object(Bucket=self.bucket, Key=self.key(sha256))
        self.registry.forget(sha256, claim)
        return size

    def restore_set_aside(self) -> int:
        """Nothing to undo: a stopped collector's claims lapse by themselves."""
        return 0

    def ping(self) -> None:
        with self._answering("checking the bucket"):
            self.client.head_bucket(Bucket=self.bucket)

    def _size(self, sha256: str) -> int | None:
        """The size of the blob's object, or None when there is none."""
        with self._answering(f"looking up blob {sha256}"):
            try:
                head = self.client.head_object(Bucket=self.bucket, Key=self.key(sha256))
            except ClientError as exc:
                if _error_code(exc) in _MISSING:
                    return None
                raise
            return int(head["ContentLength"])

    def _answering(self, doing: str) -> AbstractContextManager[None]:
        return _answering(f"{doing} in bucket {self.bucket}")


@contextmanager
def _answering(doing: str) -> Iterator[None]:
    """Turn the SDK's errors (no answer, access denied, no such bucket) into :class:`ObjectStoreUnavailable`
    that says what was being done."""
    try:
        yield
    except ClientError as exc:
        raise ObjectStoreUnavailable(f"{doing}: {exc}") from exc
    except BotoCoreError as exc:
        raise ObjectStoreUnavailable(f"{doing}: {exc}") from exc


def _error_code(error: ClientError) -> str:
    return str(error.response.get("Error", {}).get("Code", ""))
