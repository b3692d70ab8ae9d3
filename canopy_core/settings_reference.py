"""Every measurement setting as a reference for people, written from the configuration itself.

``canopy settings`` prints it and docs/configuration.md holds it (a test keeps the two the same), so the
names, defaults and meanings a user reads are the ones the measurement runs with.
"""

from __future__ import annotations

import json

from pydantic import BaseModel

from canopy_core.config import MeasureConfig

__all__ = ["settings_reference"]

_INTRODUCTION = """\
# Measurement settings

Every setting of the measurement, its default and what it means, by section. Most units are in the
names: `_m` metres, `_deg` degrees, `_px` pixels; for the others (counts, shares, switches, OpenCV's hue
units) the meaning says. A capture's own settings, capture.json's `calibration_balls` (the `balls`
settings `diameter_m`, `colors` and `hsv`) and `roi`, replace these defaults for that capture, and the
ways below replace both.

A setting is changed for one measurement, never for good:

- offline: `canopy measure CAPTURE --set metrics.max_thin_top_m=0.4` (and `canopy balls`; `--set` may be
  given more than once; its value is JSON: `0.4`, `true`, `["red", "blue"]`);
- through the service: the job's optional body, `{"config": {"metrics": {"max_thin_top_m": 0.4}}}` (see
  docs/api.md);
- in the capture itself: capture.json's `calibration_balls` and `roi` (see docs/capture-format.md).

A setting that does not exist or a value out of its range is refused with an error naming the setting
(the service answers `422 invalid_config`). The defaults were tuned on simulated captures, on the seeds
docs/design.md names; change one only for a reason the capture gives, such as a crown wider than the
region of interest or a leader whose bare tip is longer than a stake's would be.

This page is written by `canopy settings` from the code; edit the settings' descriptions in
canopy_core/config.py, not here.
"""


def settings_reference() -> str:
    """The settings reference as Markdown: per section of :class:`MeasureConfig` its purpose, then a table
    of each setting's dotted name, default and description."""
    defaults = MeasureConfig()
    parts = [_INTRODUCTION]
    for section in MeasureConfig.model_fields:
        model: BaseModel = getattr(defaults, section)
        values = model.model_dump(mode="json")
        parts.append(f"\n## `{section}`\n\n{_purpose(type(model))}\n\n")
        parts.append("| setting | default | meaning |\n| --- | --- | --- |\n")
        for name, field in type(model).model_fields.items():
            default = json.dumps(values[name])
            parts.append(f"| `{section}.{name}` | `{default}` | {_cell(field.description or '')} |\n")
    return "".join(parts)


def _purpose(model: type[BaseModel]) -> str:
    """The first paragraph of a section's docstring, on one line, with Markdown's code quotes."""
    paragraph = (model.__doc__ or "").strip().split("\n\n")[0]
    return " ".join(paragraph.split()).replace("``", "`")


def _cell(text: str) -> str:
    """``text`` fit for one cell of a Markdown table."""
    return " ".join(text.split()).replace("|", "\\|")
