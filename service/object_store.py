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
import re
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

import boto3
from botocore.config import Config
from botocore.exceptions import BotoCoreError, ClientError

from service.blob_registry import BlobRegistry
from service.storage import BlobStore, IncomingBlob, ObjectStoreUnavailable, check_digest

if TYPE_CHECKING:
    from mypy_boto3_s3 import S3Client

__all__ = ["ObjectStore", "s3_client"]

_MISSING = ("404", "NoSuchKey", "NotFound")


def s3_client(endpoint_url: str | None, *, attempts: int, timeout_s: float = 60.0) -> S3Client:
    """A client for the S3 API at ``endpoint_url`` (None: AWS itself) that tries a request ``attempts``
    times in all, each connection and each read waiting at most ``timeout_s``."""
    config = Config(
        retries={"total_max_attempts": attempts, "mode": "standard"},
        connect_timeout=timeout_s,
        read_timeout=timeout_s,
    )
    return boto3.client("s3", endpoint_url=endpoint_url, config=config)


class ObjectStore(BlobStore):
    """Blobs in ``bucket`` of the S3 API at ``endpoint_url`` under ``prefix``, each request tried
    ``attempts`` times; incoming ones spooled in ``spool_dir`` (see the module).

    Deletes and the readiness probe go through a second client that tries once and gives up within a
    quarter of the collector's claim for connecting and as much for the answer: a delete must be over
    before any writer may take a claimed blob over (see ``service/blob_registry.py``), and a probe must
    answer while the prober still waits.
    """

    def __init__(
        self,
        endpoint_url: str | None,
        bucket: str,
        *,
        prefix: str,
        registry: BlobRegistry,
        spool_dir: Path,
        attempts: int,
        min_free_bytes: int = 0,
    ) -> None:
        super().__init__(spool_dir, min_free_bytes=min_free_bytes)
        self.client = s3_client(endpoint_url, attempts=attempts)
        self._once = s3_client(endpoint_url, attempts=1, timeout_s=registry.claim_s / 4)
        self.bucket = bucket
        self.prefix = prefix
        self.registry = registry
        self._key_pattern = re.compile(rf"{re.escape(prefix)}([0-9a-f]{{2}})/(\1[0-9a-f]{{62}})")

    def key(self, sha256: str) -> str:
        """The object key of the blob with this digest."""
        check_digest(sha256)
        return f"{self.prefix}{sha256[:2]}/{sha256}"

    def keep(self, incoming: IncomingBlob) -> None:
        """Reserve the blob, then write it unless an object of its size is there already and no collector
        had claimed it (a claim taken over may still see its delete arrive: the bytes are written again)."""
        sha256 = incoming.sha256
        took_over = self.registry.reserve(sha256, incoming.size_bytes)
        if not took_over and self._size(sha256) == incoming.size_bytes:
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
                    named = self._key_pattern.fullmatch(entry["Key"])
                    if named is None:  # not a blob of ours (another tool's object under the prefix)
                        continue
                    sha256 = named.group(2)
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
                self._once.delete_object(Bucket=self.bucket, Key=self.key(sha256))
        self.registry.forget(sha256, claim)
        return size

    def restore_set_aside(self) -> int:
        """Nothing to undo: a stopped collector's claims lapse by themselves."""
        return 0

    def ping(self) -> None:
        with self._answering("checking the bucket"):
            self._once.head_bucket(Bucket=self.bucket)

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
    except (ClientError, BotoCoreError) as exc:
        raise ObjectStoreUnavailable(f"{doing}: {exc}") from exc


def _error_code(error: ClientError) -> str:
    return str(error.response.get("Error", {}).get("Code", ""))
