"""What every request and the worker share: the settings, the database and the blob store."""

from __future__ import annotations

from dataclasses import dataclass

from service.blob_registry import BlobRegistry
from service.database import Database
from service.settings import Settings
from service.storage import BlobStore, FolderStore

__all__ = ["Context", "open_blob_store"]


def open_blob_store(settings: Settings, database: Database) -> BlobStore:
    """The blob store the settings name: the folder ``data_dir/blobs``, or the S3 bucket ``s3_bucket``
    (whose register of blobs is in ``database``). Creates the local folder it needs."""
    settings.spool_dir.mkdir(parents=True, exist_ok=True)
    if settings.s3_bucket is None:
        return FolderStore(settings.blob_dir, min_free_bytes=settings.min_free_bytes)
    # Imported here: boto3 takes a quarter of a second to load, which every worker's forkserver would pay
    # at start (and make a worker stopped at once wait for) when no bucket is configured.
    from service.object_store import ObjectStore

    return ObjectStore(
        settings.s3_endpoint_url,
        settings.s3_bucket,
        prefix=settings.s3_prefix,
        registry=BlobRegistry(database, claim_s=settings.blob_claim_s),
        spool_dir=settings.spool_dir,
        attempts=settings.s3_attempts,
        min_free_bytes=settings.min_free_bytes,
    )


@dataclass(frozen=True)
class Context:
    """The service's resources, built once per process from the settings."""

    settings: Settings
    database: Database
    store: BlobStore

    @classmethod
    def from_settings(cls, settings: Settings) -> Context:
        """Open the database and the blob store the settings name (creating the data folder)."""
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        database = Database(settings.sqlalchemy_url)
        return cls(settings=settings, database=database, store=open_blob_store(settings, database))
