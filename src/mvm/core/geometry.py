"""Multi-view geometry on batched arrays: projection, DLT triangulation. Pure numpy, no I/O.

Conventions: world -> camera ``x_cam = R X + t``; projection matrices ``P = K [R | t]``;
pixel coordinates of an undistorted pinhole camera.
"""
from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices. ``v: (..., 3)`` -> ``(..., 3, 3)`` with ``skew(a) @ b == a × b``."""
    v = np.asarray(v, dtype=float)
    zero = np.zeros(v.shape[:-1])
    return np.stack([
        np.stack([zero, -v[..., 2], v[..., 1]], -1),
        np.stack([v[..., 2], zero, -v[..., 0]], -1),
        np.stack([-v[..., 1], v[..., 0], zero], -1),
    ], -2)


def project(points: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points. ``points: (..., 3)``, ``P: (..., 3, 4)`` (broadcast) ->
    pixels ``(..., 2)`` and depths ``(..., )`` (camera z; <= 0 is behind the camera).

    >>> P = np.hstack([np.eye(3), np.zeros((3, 1))])
    >>> project(np.array([2.0, 4.0, 2.0]), P)[0]
    array([1., 2.])
    """
    points = np.asarray(points, dtype=float)
    homogeneous = np.concatenate([points, np.ones(points.shape[:-1] + (1,))], axis=-1)
    x = np.einsum("...ij,...j->...i", P, homogeneous)
    depth = x[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        pixels = x[..., :2] / depth[..., None]
    return pixels, depth


def triangulate_dlt(points: np.ndarray, P: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Weighted linear (DLT) triangulation, batched.

    Args:
        points: ``(..., M, 2)`` observations of one point in ``M`` views.
        P: ``(..., M, 3, 4)`` projection matrices.
        weights: ``(..., M)`` non-negative weights; 0 drops a view. Default 1.
    Returns:
        ``(..., 3)`` points minimizing the weighted algebraic error (NaN where fewer than two
        views have weight).

    For conditioning, pass normalized coordinates (``K^-1 x`` with ``[R | t]``) where the
    intrinsics are large; the result is the same point.
    """
    points = np.asarray(points, dtype=float)
    if weights is None:
        weights = np.ones(points.shape[:-1])
    w = np.asarray(weights, dtype=float)[..., None]
    rows_x = points[..., 0:1] * P[..., 2, :] - P[..., 0, :]   # (..., M, 4)
    rows_y = points[..., 1:2] * P[..., 2, :] - P[..., 1, :]
    rows_x = rows_x / np.maximum(np.linalg.norm(rows_x, axis=-1, keepdims=True), 1e-12)
    rows_y = rows_y / np.maximum(np.linalg.norm(rows_y, axis=-1, keepdims=True), 1e-12)
    normal = np.einsum("...mi,...mj->...ij", w**2 * rows_x, rows_x) + \
        np.einsum("...mi,...mj->...ij", w**2 * rows_y, rows_y)
    _, vectors = np.linalg.eigh(normal)
    X = vectors[..., :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        result = X[..., :3] / X[..., 3:4]
    enough = (np.asarray(weights) > 0).sum(axis=-1) >= 2
    result[~enough] = np.nan
    return result


def ray_spread_deg(directions: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Parallax of a bundle of rays, in degrees: the largest angle between the masked ray
    farthest from the bundle's mean direction and any other masked ray (a two-sweep estimate
    of the largest pairwise angle: exact on an arc, never below half of it).

    ``directions: (..., M, 3)`` unit vectors, ``mask: (..., M)`` bool -> ``(...)`` (0 with < 2 rays).
    """
    d = np.where(mask[..., None], directions, 0.0)
    mean = d.sum(axis=-2)
    mean /= np.maximum(np.linalg.norm(mean, axis=-1, keepdims=True), 1e-12)
    cos_mean = np.where(mask, (d * mean[..., None, :]).sum(-1), 2.0)
    far = np.take_along_axis(d, np.argmin(cos_mean, axis=-1)[..., None, None], axis=-2)  # (..., 1, 3)
    cos = np.where(mask, (d * far).sum(-1), 1.0)
    return np.degrees(np.arccos(np.clip(cos.min(axis=-1), -1.0, 1.0)))
