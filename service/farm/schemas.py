"""What the farm endpoints answer."""

from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel

__all__ = ["MeasurementSummary", "OrchardOut", "RowOut", "TreeOut"]


class OrchardOut(BaseModel):
    id: int
    name: str
    created_at: datetime


class RowOut(BaseModel):
    id: int
    orchard_id: int
    name: str
    created_at: datetime


class MeasurementSummary(BaseModel):
    """A measurement's headline metrics (merged views, metres); the whole document is at ``href``."""

    id: int
    job_id: int
    capture_id: int
    tree_id: int
    captured_at: datetime
    height_m: float
    width_m: float
    thickness_m: float
    created_at: datetime
    href: str


class TreeOut(BaseModel):
    """A tree of a row, with its most recent measurement (by capture time)."""

    id: int
    row_id: int
    name: str
    created_at: datetime
    latest_measurement: MeasurementSummary | None
