"""Reading and writing coloured point clouds as binary PLY (metres, RGB as 8-bit)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d

__all__ = ["read_ply", "write_ply"]


def write_ply(path: str | Path, points_m: np.ndarray, colors_rgb: np.ndarray | None = None) -> Path:
    """Write ``(N, 3)`` points (and ``(N, 3)`` uint8 colours) to a binary little-endian PLY file."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points_m, dtype=np.float64)))
    if colors_rgb is not None:
        cloud.colors = o3d.utility.Vector3dVector(np.asarray(colors_rgb, dtype=np.float64) / 255.0)
    target = Path(path)
    if not o3d.io.write_point_cloud(target, cloud, write_ascii=False, compressed=False):
        raise OSError(f"could not write the point cloud to {target}")
    return target


def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (m) and, when the file has them, uint8 RGB colours of a PLY file."""
    cloud = o3d.io.read_point_cloud(Path(path))
    if not cloud.has_points():
        raise OSError(f"{path} holds no points or is not a readable PLY file")
    colors = np.rint(np.asarray(cloud.colors) * 255).astype(np.uint8) if cloud.has_colors() else None
    return np.asarray(cloud.points), colors
