"""Coarse registration of views from the calibration balls' centres, and small tools for 4x4 poses.

Two constructions of the rigid map from one view's ball centres to another's:

- :func:`register_by_balls`, the least-squares rigid transform (Kabsch/Umeyama without scale), which uses
  all centres and spreads their detection errors; the one the pipeline uses.
- :func:`paper_transform`, the paper's construction (Yang et al. 2019, eqs. 1-4): each view's ball
  triangle is moved to its centroid M, its normal p rotated onto z by Rx(alpha) then Ry(beta), and the
  vector to the yellow ball onto x by Rz(gamma); it trusts the yellow ball's direction exactly and is kept
  for comparison and tests. On exact centres both agree.

Poses are 4x4 numpy arrays mapping points of one frame into another (``target_from_source``).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "apply",
    "canonical_ball_frame",
    "invert",
    "paper_transform",
    "pose_change",
    "register_by_balls",
    "rotation_x",
    "rotation_y",
    "rotation_z",
]


def apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points ``(N, 3)`` mapped by a 4x4 rigid transform."""
    return points @ transform[:3, :3].T + transform[:3, 3]


def invert(transform: np.ndarray) -> np.ndarray:
    """The inverse of a 4x4 rigid transform (without a general matrix inverse)."""
    rotation = transform[:3, :3]
    out = np.eye(4)
    out[:3, :3] = rotation.T
    out[:3, 3] = -rotation.T @ transform[:3, 3]
    return out


def pose_change(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """How far pose ``b`` is from pose ``a``: ``(translation_m, rotation_deg)`` of ``b @ inv(a)``."""
    delta = b @ invert(a)
    angle = Rotation.from_matrix(delta[:3, :3]).magnitude()
    return float(np.linalg.norm(delta[:3, 3])), float(np.degrees(angle))


def register_by_balls(source_centres: np.ndarray, target_centres: np.ndarray) -> np.ndarray:
    """Least-squares rigid transform taking ``source_centres`` onto ``target_centres`` (no scale).

    Parameters
    ----------
    source_centres, target_centres
        ``(N, 3)`` matching ball centres, N >= 3, not collinear.

    Returns
    -------
    numpy.ndarray
        4x4 ``target_from_source``.

    References
    ----------
    Umeyama, S. (1991). Least-squares estimation of transformation parameters between two point
    patterns. IEEE TPAMI 13(4), 376-380 (with the scale fixed to 1).
    """
    source = np.asarray(source_centres, dtype=float)
    target = np.asarray(target_centres, dtype=float)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3:
        raise ValueError(f"centre arrays must both be (N, 3); got {source.shape} and {target.shape}")
    if source.shape[0] < 3:
        raise ValueError(f"at least 3 ball centres are needed, got {source.shape[0]}")
    source_mean = source.mean(axis=0)
    target_mean = target.mean(axis=0)
    covariance = (target - target_mean).T @ (source - source_mean)
    u, singular, vt = np.linalg.svd(covariance)
    if singular[1] < 1e-9 * max(singular[0], 1e-12):
        raise ValueError("ball centres are collinear; the rotation is undetermined")
    reflection = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ reflection @ vt
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = target_mean - rotation @ source_mean
    return out


def rotation_x(angle_rad: float) -> np.ndarray:
    """3x3 rotation about x by ``angle_rad`` (right hand)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_y(angle_rad: float) -> np.ndarray:
    """3x3 rotation about y by ``angle_rad`` (right hand)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_z(angle_rad: float) -> np.ndarray:
    """3x3 rotation about z by ``angle_rad`` (right hand)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def canonical_ball_frame(red: np.ndarray, yellow: np.ndarray, blue: np.ndarray) -> np.ndarray:
    """The paper's canonical frame of a ball triangle (eqs. 1-3), as 4x4 ``canonical_from_view``.

    The centroid M goes to the origin; the triangle's normal p = (Y - R) x (B - R) is rotated onto +z by
    Rx(alpha) then Ry(beta); then Rz(gamma) turns the vector M->Y onto +x.
    """
    centres = np.stack([red, yellow, blue]).astype(float)
    centroid = centres.mean(axis=0)
    normal = np.cross(centres[1] - centres[0], centres[2] - centres[0])
    if np.linalg.norm(normal) < 1e-9:
        raise ValueError("ball centres are collinear; the triangle has no normal")
    alpha = np.arctan2(normal[1], normal[2])
    rx = rotation_x(alpha)
    normal_x = rx @ normal
    beta = np.arctan2(-normal_x[0], normal_x[2])
    ryx = rotation_y(beta) @ rx
    to_yellow = ryx @ (centres[1] - centroid)
    gamma = -np.arctan2(to_yellow[1], to_yellow[0])
    rotation = rotation_z(gamma) @ ryx
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = -rotation @ centroid
    return out


def paper_transform(source_centres: np.ndarray, target_centres: np.ndarray) -> np.ndarray:
    """The paper's coarse registration (eq. 4): ``inv(canonical(target)) @ canonical(source)``.

    Both arrays hold the red, yellow and blue centres, in that order, as rows.
    """
    source = np.asarray(source_centres, dtype=float)
    target = np.asarray(target_centres, dtype=float)
    if source.shape != (3, 3) or target.shape != (3, 3):
        raise ValueError("the paper's construction takes exactly the red, yellow and blue centres")
    return invert(canonical_ball_frame(*target)) @ canonical_ball_frame(*source)
