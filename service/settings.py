"""The service's and worker's settings, read once from ``CANOPY_*`` environment variables."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from canopy_core.images import DEFAULT_MAX_PIXELS

__all__ = ["Settings"]


class Settings(BaseSettings):
    """Where data lives, request limits and the job queue's timing; every field from ``CANOPY_<NAME>``.

    The default is the embedded one: a SQLite file and a blob folder under ``./canopy-data``. Setting
    ``CANOPY_DATABASE_URL`` (for instance ``postgresql+psycopg://host/db``) moves the records elsewhere;
    uploaded files and fused clouds stay under ``data_dir``.
    """

    model_config = SettingsConfigDict(env_prefix="CANOPY_", frozen=True)

    data_dir: Path = Field(Path("canopy-data"), description="Folder of the SQLite file and the blob store.")
    database_url: str | None = Field(None, description="SQLAlchemy URL; default: SQLite in data_dir.")
    max_upload_bytes: int = Field(128 * 1024 * 1024, gt=0, description="Largest accepted file body.")
    max_image_pixels: int = Field(DEFAULT_MAX_PIXELS, gt=0, description="Largest accepted image.")
    job_lease_s: float = Field(30.0, gt=0, description="A worker silent this long loses its job.")
    job_max_attempts: int = Field(3, ge=1, description="Attempts before a crashing job stays failed.")
    job_timeout_s: float = Field(600.0, gt=0, description="A measurement running longer is stopped.")
    worker_poll_s: float = Field(0.5, gt=0, description="Pause between claims when the queue is empty.")

    @cached_property
    def sqlalchemy_url(self) -> str:
        """The database URL in use."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'canopy.db').resolve()}"

    @cached_property
    def blob_dir(self) -> Path:
        """Folder of the content-addressed store of uploaded files and fused clouds."""
        return self.data_dir.resolve() / "blobs"

    @property
    def job_heartbeat_s(self) -> float:
        """How often a worker renews its lease: three chances before it runs out."""
        return self.job_lease_s / 3
