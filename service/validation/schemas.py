"""What the validation endpoints take and answer (metres)."""

from __future__ import annotations

from datetime import date, datetime

from pydantic import BaseModel, Field

__all__ = ["ManualReceipt", "ModeMetricRow", "Pair", "Unmatched", "Validation"]


class ManualReceipt(BaseModel):
    """What an upload of manual measurements changed: lines read, records new and records replaced (a
    tree measured on the same day again, or the same file sent twice)."""

    lines: int
    created: int
    replaced: int


class Metrics(BaseModel):
    height_m: float | None
    width_m: float | None
    thickness_m: float | None


class Pair(BaseModel):
    """A manual measurement and the tree's measurement nearest in time to it, per view mode."""

    orchard: str
    row: str
    tree: str
    measured_on: date
    manual: Metrics
    measurement_id: int
    captured_at: datetime
    days_apart: float = Field(description="From noon UTC of the manual day to the capture, in days")
    calculated: dict[str, Metrics] = Field(description="Per view mode (views/1, ..., merged)")


class Unmatched(BaseModel):
    """A manual measurement with no measurement to compare with, and why."""

    orchard: str
    row: str
    tree: str
    measured_on: date
    reason: str


class ModeMetricRow(BaseModel):
    """One line of Table 1: a metric in one view mode over the pairs that have both values."""

    mode: str
    metric: str
    n: int
    r2: float | None = Field(
        description="1 - SS_res / SS_tot of calculated against manual; None below 2 pairs"
    )
    rmse_m: float | None
    are_pct: float | None = Field(description="Mean of |calculated - manual| / manual, in per cent")


class Validation(BaseModel):
    window_days: float
    pairs: list[Pair]
    unmatched: list[Unmatched]
    table: list[ModeMetricRow]
