"""Fused clouds as LAS 1.4 and LAZ (laspy; LAZ compressed by lazrs), the formats GIS, forestry and lidar
software read: coordinates in metres at millimetre resolution, 16-bit RGB, and each point's ASPRS
classification (2 ground, 5 the tree, 1 other, 64 a calibration ball; see
:class:`canopy_core.cloud_io.PointClass`)."""

from __future__ import annotations

import io

import laspy
import numpy as np

from canopy_core.cloud_io import Cloud

__all__ = ["las_bytes"]

_POINT_FORMAT = 7
"""LAS 1.4 point format with RGB (and no near-infrared or waveform)."""
_RESOLUTION_M = 0.001
"""Coordinates are stored as integers of this many metres: far finer than a depth camera's noise."""


def las_bytes(cloud: Cloud, *, compressed: bool) -> bytes:
    """``cloud`` as a LAS 1.4 file, or LAZ when ``compressed``; points without a class are class 1."""
    header = laspy.LasHeader(point_format=_POINT_FORMAT, version="1.4")
    header.scales = np.full(3, _RESOLUTION_M)
    header.offsets = cloud.points_m.min(axis=0) if len(cloud) else np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = cloud.points_m[:, 0], cloud.points_m[:, 1], cloud.points_m[:, 2]
    if cloud.colors_rgb is not None:
        wide = cloud.colors_rgb.astype(np.uint16) * 257  # 8-bit to LAS's 16-bit, 255 to 65535
        las.red, las.green, las.blue = wide[:, 0], wide[:, 1], wide[:, 2]
    las.classification = cloud.classes if cloud.classes is not None else np.ones(len(cloud), dtype=np.uint8)
    stream = io.BytesIO()
    las.write(stream, do_compress=compressed)
    return stream.getvalue()
