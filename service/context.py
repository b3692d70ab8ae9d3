"""What every request and the worker share: the settings, the database and the blob store."""

from __future__ import annotations

from dataclasses import dataclass

from service.database import Database
from service.settings import Settings
from service.storage import BlobStore

__all__ = ["Context"]


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
        settings.blob_dir.mkdir(parents=True, exist_ok=True)
        return cls(
            settings=settings,
            database=Database(settings.sqlalchemy_url),
            store=BlobStore(settings.blob_dir, min_free_bytes=settings.min_free_bytes),
        )
