"""What the jobs endpoints take and answer."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["JobError", "JobOrder", "JobOut", "JobRequest", "JobState"]

JobState = Literal["queued", "running", "succeeded", "failed"]
JobOrder = Literal["newest", "oldest"]


class JobRequest(BaseModel):
    """Optional settings for a measurement: overrides of the defaults and the capture's own settings."""

    model_config = ConfigDict(extra="forbid")

    config: dict[str, Any] | None = Field(
        None,
        description='Nested MeasureConfig overrides, e.g. {"roi": {"radius_m": 2.0}}',
        examples=[{"roi": {"radius_m": 2.0}}],
    )


class JobError(BaseModel):
    """Why a job (or its last attempt) failed: a stable code, a sentence, and where when known."""

    model_config = ConfigDict(extra="allow")

    code: str
    message: str
    view: str | None = None
    file: str | None = None
    field: str | None = None
    color: str | None = None


class JobOut(BaseModel):
    """A job's state, for dashboards polling it."""

    id: int
    capture_id: int
    orchard: str
    row: str
    tree: str
    tree_id: int
    state: JobState
    stage: str | None = Field(
        description="Pipeline stage while running: load, balls, register, refine, metrics, done"
    )
    progress: float = Field(ge=0.0, le=1.0)
    attempts: int
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    error: JobError | None
    measurement_id: int | None
