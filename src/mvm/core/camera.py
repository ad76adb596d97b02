"""A pinhole camera with an OpenCV lens: projection, lens distortion and its inverse.

Arrays in, arrays out; no I/O. Conventions (those of :class:`mvm.core.scene.Cameras`): world ->
camera ``x_cam = R X + t``, projection matrices ``P = K [R | t]``, pixels of the pinhole camera
``K`` unless distorted by a lens.

A lens is a vector of OpenCV coefficients: ``[k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[,
tx, ty]]]]]`` (4, 5, 8, 12 or 14 numbers), or with ``fisheye`` OpenCV's fisheye model ``[k1, k2,
k3, k4]``. An empty vector, or an all-zero one of the first model, is no lens: the pixels stay
as they are. Every lens of mvm is one of these (COLMAP's models are converted when read,
:mod:`mvm.io.colmap`), and goes through :func:`distort` and :func:`undistort` (OpenCV);
:func:`distort_views` and :func:`undistort_views` apply the lens of each view of
:class:`~mvm.core.scene.Cameras`.

Every projection in mvm comes down to :func:`mvm.core.geometry.project` (``P`` matrices); this
module builds ``P`` from ``K, R, t`` and adds the lens.

>>> K = np.array([[100.0, 0, 50], [0, 100, 40], [0, 0, 1]])
>>> pixels, depth = project_camera(np.array([0.2, -0.1, 2.0]), K, np.eye(3), np.zeros(3))
>>> pixels, float(depth)
(array([60., 35.]), 2.0)
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from mvm.core.geometry import project as project_with_matrices
from mvm.core.keypoints import NUM_JOINTS

if TYPE_CHECKING:                                   # scene.py builds its P matrices here
    from mvm.core.scene import Cameras

#: Stopping rule of OpenCV's iterative undistortion (``cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS``,
#: iterations, change in normalized coordinates). OpenCV is imported only for a lens: 60 ms that
#: a pinhole scene does not pay.
UNDISTORT_CRITERIA = (1 | 2, 40, 1e-8)


def projection_matrix(K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``P = K [R | t]``. ``K, R: (..., 3, 3)``, ``t: (..., 3)`` -> ``(..., 3, 4)``."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    return np.asarray(K, dtype=float) @ np.concatenate([R, t[..., :, None]], axis=-1)


def normalized_points(keypoints: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels of a pinhole camera -> normalized image coordinates ``K^-1 x``.
    ``keypoints: (N, J, >=2)``, ``K: (N, 3, 3)`` or ``(3, 3)`` -> ``(N, J, 2)``.

    >>> normalized_points(np.array([[[150.0, 20.0]]]), np.array([[100.0, 0, 50], [0, 100, 40], [0, 0, 1]]))
    array([[[ 1. , -0.2]]])
    """
    K = np.broadcast_to(K, (len(keypoints), 3, 3))
    fx, fy, s = K[:, 0, 0, None], K[:, 1, 1, None], K[:, 0, 1, None]
    cx, cy = K[:, 0, 2, None], K[:, 1, 2, None]
    y = (keypoints[..., 1] - cy) / fy
    x = (keypoints[..., 0] - cx - s * y) / fx
    return np.stack([x, y], -1)


def project_camera(points: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
            distortion: np.ndarray | None = None, fisheye: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Project world points into one camera.

    Args:
        points: ``(..., 3)`` world coordinates (NaN: missing).
        K, R, t: ``(3, 3)``, ``(3, 3)``, ``(3,)`` the camera, ``x_cam = R X + t``.
        distortion: the lens (see the module), or None for a pinhole camera.
        fisheye: OpenCV's fisheye lens model.
    Returns:
        pixels ``(..., 2)`` (distorted by the lens; meaningful where the depth is > 0) and depths
        ``(...)``: camera z, <= 0 behind the camera. NaN points give NaN.
    """
    pixels, depth = project_with_matrices(points, projection_matrix(K, R, t))
    if distortion is not None:
        pixels = distort(pixels, K, distortion, fisheye)
    return pixels, depth


def project_views(cameras: Cameras, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points into every view of pinhole ``cameras``.

    ``points: (..., 3)`` -> pixels ``(V, ..., 2)`` and depths ``(V, ...)``.
    """
    points = np.asarray(points, dtype=float)
    pixels, depth = project_with_matrices(points.reshape(1, -1, 3), cameras.P)
    shape = (len(cameras),) + points.shape[:-1]
    return pixels.reshape(shape + (2,)), depth.reshape(shape)


def has_lens(distortion: np.ndarray | None, fisheye: bool = False) -> bool:
    """Whether ``distortion`` moves any pixel: not None, not empty, and a fisheye lens or not
    all zero."""
    if distortion is None or not np.size(distortion):
        return False
    return bool(fisheye) or bool(np.any(np.asarray(distortion, dtype=float)))


def _finite_rows(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``xy: (..., 2)`` -> the finite points ``(n, 2)`` and their mask ``(...)``."""
    finite = np.isfinite(xy).all(-1)
    return xy[finite].reshape(-1, 2), finite


def undistort(xy: np.ndarray, K: np.ndarray, distortion: np.ndarray | None, fisheye: bool = False) -> np.ndarray:
    """Undo the lens of one camera: distorted pixels ``xy: (..., 2)`` -> ``(..., 2)`` pixels of the
    pinhole camera ``K: (3, 3)`` (NaN stays NaN). OpenCV's iterative inversion
    (:data:`UNDISTORT_CRITERIA`)."""
    def move(points: np.ndarray, d: np.ndarray) -> np.ndarray:
        import cv2

        flat = points.reshape(-1, 1, 2)
        if fisheye:
            return cv2.fisheye.undistortPoints(flat, K, d, P=K)
        return cv2.undistortPoints(flat, K, d, R=None, P=K, criteria=UNDISTORT_CRITERIA)

    return _through_lens(xy, distortion, fisheye, move)


def distort(xy: np.ndarray, K: np.ndarray, distortion: np.ndarray | None, fisheye: bool = False) -> np.ndarray:
    """Apply the lens of one camera (the inverse of :func:`undistort`): pixels of the pinhole
    camera ``K: (3, 3)``, ``xy: (..., 2)`` -> distorted pixels ``(..., 2)`` (NaN stays NaN)."""
    def move(points: np.ndarray, d: np.ndarray) -> np.ndarray:
        import cv2

        rays = (np.concatenate([points, np.ones((len(points), 1))], axis=1) @ np.linalg.inv(K).T).reshape(-1, 1, 3)
        zero = np.zeros(3)
        project_points = cv2.fisheye.projectPoints if fisheye else cv2.projectPoints
        return project_points(rays, zero, zero, K, d)[0]

    return _through_lens(xy, distortion, fisheye, move)


def _through_lens(xy: np.ndarray, distortion: np.ndarray | None, fisheye: bool, move) -> np.ndarray:
    """``move(points: (n, 2), distortion) -> (n, 1, 2)`` applied to the finite points of
    ``xy: (..., 2)`` (NaN stays NaN); a copy of ``xy`` when the camera has no lens."""
    xy = np.asarray(xy, dtype=float)
    if not has_lens(distortion, fisheye):
        return xy.copy()
    points, finite = _finite_rows(xy)
    out = np.full(xy.shape, np.nan)
    if len(points):
        out[finite] = move(points, np.asarray(distortion, dtype=float).reshape(-1)).reshape(-1, 2)
    return out


def undistort_views(cameras: Cameras, xy: np.ndarray, view: np.ndarray) -> np.ndarray:
    """Undo the lens of each view: distorted pixels ``xy: (N, ..., 2)`` seen in ``view: (N,)``
    (indices into ``cameras``) -> pixels ``(N, ..., 2)`` of each view's pinhole ``K`` (NaN stays
    NaN; :func:`undistort`)."""
    return _views_through_lens(cameras, xy, view, undistort)


def distort_views(cameras: Cameras, xy: np.ndarray, view: np.ndarray) -> np.ndarray:
    """Apply the lens of each view (the inverse of :func:`undistort_views`): pinhole pixels
    ``xy: (N, ..., 2)`` of ``view: (N,)`` -> distorted pixels ``(N, ..., 2)`` (:func:`distort`)."""
    return _views_through_lens(cameras, xy, view, distort)


def _views_through_lens(cameras: Cameras, xy: np.ndarray, view: np.ndarray, lens) -> np.ndarray:
    """``lens(xy, K, distortion, fisheye)`` applied to the rows of ``xy: (N, ..., 2)`` of each
    view of ``view: (N,)``."""
    out = np.array(xy, dtype=float)
    view = np.asarray(view)
    for v in np.unique(view):
        if has_lens(cameras.distortion[v], cameras.fisheye[v]):
            rows = view == v
            out[rows] = lens(out[rows], cameras.K[v], cameras.distortion[v], bool(cameras.fisheye[v]))
    return out


def project_persons(keypoints3d: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                    size: tuple[float, float], reference: str = "image") -> tuple[np.ndarray, np.ndarray]:
    """Project persons into one view.

    Args:
        keypoints3d: ``(P, 17, 3)`` world coordinates, NaN where missing.
        K, R, t: ``(3, 3)``, ``(3, 3)``, ``(3,)`` pinhole camera, ``x_cam = R X + t``.
        size: ``(width, height)`` of the image in pixels.
        reference: ``'image'``: depths relative to the median camera z of all labelled joints
            of the view; ``'person'``: of each person's own labelled joints.
    Returns:
        keypoints ``(P, 17, 3)``: x, y and v = 2 where the joint exists, lies in front of the
        camera and inside the image, else 0 (and x = y = 0);
        depths ``(P, 17)``: camera z over the reference camera z, 0 where the joint is not labelled.
    """
    if reference not in ("image", "person"):
        raise ValueError(f"reference: expected 'image' or 'person', got {reference!r}")
    X = np.asarray(keypoints3d, dtype=float).reshape(-1, NUM_JOINTS, 3)
    uv, z = project_camera(X, K, R, t)                                            # (P, 17, 2), (P, 17)
    w, h = float(size[0]), float(size[1])
    ok = (np.isfinite(uv).all(-1) & np.isfinite(z) & (z > 1e-9)
          & (uv[..., 0] >= 0) & (uv[..., 0] <= w - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= h - 1))
    keypoints = np.zeros(X.shape[:2] + (3,))
    keypoints[ok, :2] = uv[ok]
    keypoints[ok, 2] = 2.0
    depths = np.zeros(X.shape[:2])
    zz = np.where(ok, z, np.nan)
    has = ok.any(axis=1)
    if has.any():
        med = np.nanmedian(zz[has], axis=1, keepdims=True) if reference == "person" else np.nanmedian(zz[has])
        depths[has] = np.nan_to_num(zz[has] / med, nan=0.0)
    return keypoints, depths
