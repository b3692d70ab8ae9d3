"""What the farm endpoints answer."""

from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel

__all__ = [
    "MeasurementSummary",
    "MetricStats",
    "OrchardOut",
    "OrchardSummary",
    "Outlier",
    "RowOut",
    "Summary",
    "TreeOut",
]


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


class MetricStats(BaseModel):
    """One metric over the trees of a row or orchard (its unit is the metric's: m, m², m³)."""

    count: int
    mean: float
    median: float
    min: float
    max: float
    std: float | None
    """Sample standard deviation; None with fewer than two trees."""


class Outlier(BaseModel):
    """A tree whose metric lies more than two standard deviations from the mean of its row or orchard."""

    tree_id: int
    tree: str
    row: str
    metric: str
    value: float
    deviations: float
    """(value - mean) / standard deviation."""


class Summary(BaseModel):
    """The latest measurement of each tree of a row or an orchard, summed up per metric."""

    scope: str
    """``row`` or ``orchard``."""
    id: int
    name: str
    orchard: str
    trees: int
    """Trees in it."""
    measured_trees: int
    metrics: dict[str, MetricStats]
    outliers: list[Outlier]


class OrchardSummary(Summary):
    """An orchard's summary, with each of its rows'."""

    rows: list[Summary]
