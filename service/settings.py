"""The service's and worker's settings, read once from ``CANOPY_*`` environment variables."""

from __future__ import annotations

import difflib
import logging
import os
from functools import cached_property
from pathlib import Path
from typing import Any

from pydantic import Field, ValidationError
from pydantic_settings import BaseSettings, SettingsConfigDict

from canopy_core.images import DEFAULT_MAX_PIXELS

__all__ = ["Settings", "SettingsError", "load_settings"]

logger = logging.getLogger(__name__)

_CLOSE_NAME = 0.85
"""A ``CANOPY_*`` variable that is no setting but whose name is at least this similar to one's (difflib's
ratio, without the prefix) is taken for a misspelt setting and warned about: ``DATADIR`` is 0.93 like
``DATA_DIR`` and ``JOB_LEASE`` 0.90 like ``JOB_LEASE_S``, where ``S3_REGION`` is 0.67 like ``S3_PREFIX``."""


class Settings(BaseSettings):
    """Where data lives, request limits and the job queue's timing; every field from ``CANOPY_<NAME>``.

    The default is the embedded one: a SQLite file and a blob folder under ``./canopy-data``. Setting
    ``CANOPY_DATABASE_URL`` (for instance ``postgresql+psycopg://host/db``) moves the records elsewhere;
    setting ``CANOPY_S3_BUCKET`` moves uploaded files and fused clouds into an S3-compatible object store
    (uploads are still spooled under ``data_dir`` while they arrive).
    """

    model_config = SettingsConfigDict(env_prefix="CANOPY_", frozen=True)

    data_dir: Path = Field(Path("canopy-data"), description="Folder of the SQLite file and the blob store.")
    database_url: str | None = Field(None, description="SQLAlchemy URL; default: SQLite in data_dir.")
    max_upload_bytes: int = Field(128 * 1024 * 1024, gt=0, description="Largest accepted image body, bytes.")
    max_json_bytes: int = Field(
        1024 * 1024, gt=0, description="Largest accepted capture.json or camera.json body, bytes."
    )
    max_csv_bytes: int = Field(
        16 * 1024 * 1024, gt=0, description="Largest accepted CSV of manual measurements, bytes."
    )
    max_image_pixels: int = Field(DEFAULT_MAX_PIXELS, gt=0, description="Largest accepted image.")
    session_ttl_s: float = Field(
        12 * 3600.0,
        gt=0,
        description="A browser signed in to the dashboard stays signed in this long, seconds (a field day).",
    )
    validation_window_days: float = Field(
        14.0,
        gt=0,
        description="A manual measurement is compared with the tree's measurement captured nearest to it "
        "within this many days (a request may ask for another window): a tree grows.",
    )
    upload_idle_timeout_s: float = Field(
        30.0,
        gt=0,
        description="A request body of which no byte arrives for this long is given up (408): a client gone "
        "out of range mid-upload leaves its connection open, and would hold its upload slot.",
    )
    shutdown_grace_s: int = Field(
        10,
        ge=0,
        description="On SIGTERM or Ctrl-C the API stops taking connections and gives the requests under way "
        "this long to finish, seconds; then it cancels them and exits. An upload cancelled so was never "
        "acknowledged: its client sends it again. Without it, a client gone out of range mid-upload would "
        "hold the shutdown for upload_idle_timeout_s.",
    )
    max_concurrent_uploads: int = Field(
        16,
        gt=0,
        description="File bodies received at once (each streams to disk); one more gets 503 with "
        "Retry-After.",
    )
    max_uploads_per_key: int = Field(
        4,
        gt=0,
        description="File bodies received at once for one API key; one more gets 429 with Retry-After, so a "
        "few clients cannot take every slot.",
    )
    max_concurrent_image_checks: int = Field(
        2,
        gt=0,
        description="Uploaded images decoded at once to check them; the others wait. Each holds its pixels "
        "(up to 4 bytes per pixel of max_image_pixels) while it is checked: this bounds the API's memory.",
    )
    min_free_bytes: int = Field(
        256 * 1024 * 1024,
        ge=0,
        description="Free space kept on the data disk, bytes: below it uploads and new captures get 507 with "
        "Retry-After, and workers claim no job, so the database always has room to commit.",
    )
    stale_upload_s: float = Field(
        600.0,
        gt=0,
        description="A temporary file of an upload untouched this long is from an upload that ended "
        "unfinished (a killed server, a dropped connection) and is removed, at start-up and every "
        "stale_upload_s / 4 seconds after.",
    )
    blob_gc_grace_s: float = Field(
        3600.0,
        ge=0,
        description="`canopy gc` removes a blob no record names only when it was last stored more than this "
        "long ago, seconds: the records naming a blob are written seconds after it, never an hour.",
    )
    s3_bucket: str | None = Field(
        None,
        description="Keep blobs in this bucket of an S3-compatible object store instead of the folder "
        "data_dir/blobs; credentials and region from the AWS SDK's environment (AWS_ACCESS_KEY_ID, ...).",
    )
    s3_prefix: str = Field("blobs/", description="Key prefix of the blobs in s3_bucket.")
    s3_endpoint_url: str | None = Field(
        None, description="The object store's URL (MinIO: http://host:9000); unset: AWS S3."
    )
    s3_attempts: int = Field(5, ge=1, description="Tries of one object-store request in all (1: no retry).")
    blob_claim_s: float = Field(
        60.0,
        gt=0,
        description="How long the garbage collector's claim on a blob in the object store lasts, seconds: "
        "it starts a delete only within the first half and gives each delete a quarter to connect and a "
        "quarter to be answered; a writer of the same bytes waits at most this long.",
    )
    job_lease_s: float = Field(30.0, gt=0, description="A worker silent this long loses its job.")
    job_max_attempts: int = Field(3, ge=1, description="Attempts before a crashing job stays failed.")
    job_timeout_s: float = Field(600.0, gt=0, description="A measurement running longer is stopped.")
    worker_poll_s: float = Field(0.5, gt=0, description="Pause between claims when the queue is empty.")
    worker_metrics_port: int | None = Field(
        None,
        ge=1,
        le=65535,
        description="A worker answers Prometheus on this port (/metrics) when set: job durations by outcome "
        "and by pipeline stage. Unset: no port is opened.",
    )
    worker_view_processes: int | None = Field(
        None,
        ge=1,
        description="How many of a capture's views a measurement filters and searches for balls at once, and "
        "cuts the regions of interest of, each in a process of its own (unset: one per CPU the worker may "
        "use; 1: one at a time, for a machine whose cores run other workers). The figures are the same "
        "either way.",
    )
    worker_nice: int = Field(
        10,
        ge=0,
        le=19,
        description="CPU niceness the worker and its measurements run at: on a machine shared with the API, "
        "requests are answered first and measurements take the CPU left over (0: same as the API).",
    )

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

    @cached_property
    def spool_dir(self) -> Path:
        """Folder where uploads arrive before they are stored: the blob folder itself, or beside it when
        the blobs live in an object store."""
        return self.data_dir.resolve() / ("spool" if self.s3_bucket else "blobs")

    @property
    def job_heartbeat_s(self) -> float:
        """How often a worker renews its lease: three chances before it runs out."""
        return self.job_lease_s / 3


class SettingsError(ValueError):
    """``CANOPY_*`` settings that do not hold; the message names each variable, its value and the fault."""


def load_settings(*, warn: bool = True, **given: Any) -> Settings:
    """The settings from the ``CANOPY_*`` environment, with ``given`` (a command's options) over it.

    Raises :class:`SettingsError` with one line naming every wrong setting, for a command to print as it
    is: a typo in a deployment's environment should read as the variable to fix, not as a traceback. A
    ``CANOPY_*`` variable named like a setting but none is warned about: it would be ignored, and the
    setting left at its default (``CANOPY_DATADIR`` would keep the records in ``./canopy-data``); ``warn``
    False leaves that to another process (``canopy up``'s worker, whose ``canopy up`` warned already).
    """
    if warn:
        _warn_of_misspelt_names()
    try:
        return Settings(**given)
    except ValidationError as exc:
        problems = []
        for error in exc.errors():
            field = str(error["loc"][0]) if error["loc"] else ""
            name = field if field in given else f"CANOPY_{field.upper()}"
            problems.append(f"{name}={error['input']!r}: {error['msg']}")
        raise SettingsError("; ".join(problems)) from None


def _warn_of_misspelt_names() -> None:
    """Log a warning for each ``CANOPY_*`` environment variable that is no setting but close to one's name
    (others, such as the upload client's ``CANOPY_KEY``, are another program's). The names are compared
    without the prefix they all share, which would make any two look alike."""
    fields = [field.upper() for field in Settings.model_fields]
    for variable in sorted(os.environ):
        name = variable.removeprefix("CANOPY_")
        if name == variable or name in fields:
            continue
        close = difflib.get_close_matches(name, fields, n=1, cutoff=_CLOSE_NAME)
        if close:
            logger.warning(
                "%s is no Canopy setting and is ignored; did you mean CANOPY_%s?", variable, close[0]
            )
