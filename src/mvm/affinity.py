"""The affinity of two 2D poses (paper Eq. 1, 2): A = S · 1 / (1 + exp(γ D)).

Units of D. Eq. 2 averages point-to-epipolar-line distances over the joints both poses have.
The paper measures them in normalized image coordinates; here a distance measured in view
``u``'s pixels is divided by ``distance_scale · f_u`` (``f_u`` that view's focal length in
pixels). The unit is therefore a fixed *angle* (``distance_scale`` radians, 0.01 ≈ 0.57° by
default), the same for 640-px and 1920-px frames of the same lens, and γ is dimensionless.

With γ = 1 and distance_scale = 0.01, D = 0 gives A = 0.5 · S, an error of 1% of the focal
length gives 0.27 · S and 3% gives 0.05 · S.
"""
from __future__ import annotations

import numpy as np

from .geometry import skew
from .scene import Cameras


def epipolar_distance(cameras: Cameras, keypoints: np.ndarray, view: np.ndarray,
                      keypoint_threshold: float, distance_scale: float,
                      min_common_keypoints: int = 1, dtype=np.float32) -> np.ndarray:
    """Geometric distance D (Eq. 2) of every pair of 2D poses.

    Args:
        cameras: the ``V`` views.
        keypoints: ``(N, 17, 3)`` x, y (pixels), confidence.
        view: ``(N,)`` view of each pose.
        keypoint_threshold: keypoints below this confidence are missing.
        distance_scale: the unit of D as a fraction of the focal length.
        min_common_keypoints: pairs sharing fewer keypoints get D = inf.
    Returns:
        ``D: (N, N)`` symmetric; ``inf`` for poses of the same view; NaN (undefined) for pairs
        of views with no baseline (no epipolar geometry) and pairs with too few common keypoints.

    Cost: one ``(17, n_v, 3) @ (17, 3, N)`` product per view ``v`` with ``n_v`` poses, i.e.
    ``O(17 · N²)`` multiply-adds in ``dtype``, and ``O(N²)`` memory.
    """
    N, J = keypoints.shape[:2]
    visible = keypoints[:, :, 2] >= max(keypoint_threshold, 1e-9)
    homogeneous = np.concatenate([keypoints[:, :, :2], np.ones((N, J, 1))], axis=2)
    homogeneous[~visible] = 0.0                                     # missing joints add nothing

    used = np.unique(view)
    centers = cameras.centers
    baseline = np.linalg.norm(centers[:, None] - centers[None], axis=-1)
    scale = np.median(baseline[np.ix_(used, used)]) if len(used) > 1 else 1.0
    no_baseline = baseline <= 1e-9 * max(scale, 1e-12)

    # Every keypoint as a world ray in Plücker coordinates (moment m = C × b, direction b):
    # the epipolar line of that keypoint in view i is K_i^-T R_i (m − C_i × b) = M_i [m; b].
    K_inv = np.linalg.inv(cameras.K)
    b = np.einsum("nba,nbc,njc->nja", cameras.R[view], K_inv[view], homogeneous)   # R^T K^-1 x
    plucker = np.concatenate([np.cross(centers[view][:, None], b), b], axis=2)            # (N, J, 6)
    M = np.einsum("vba,vbc,vcd->vad", K_inv, cameras.R,
                  np.concatenate([np.broadcast_to(np.eye(3), (len(cameras), 3, 3)), -skew(centers)], axis=2))
    unit = distance_scale * cameras.focal
    plucker = np.ascontiguousarray(plucker.transpose(1, 2, 0), dtype=dtype)             # (J, 6, N)
    M = M.astype(dtype)

    # sums[u, n]: Σ_joints distance of x_u to the epipolar line of x_n, in view(u)'s unit.
    sums = np.zeros((N, N), dtype=dtype)
    points = homogeneous.transpose(1, 0, 2).astype(dtype)                          # (J, N, 3)
    for v in used:
        rows = np.flatnonzero(view == v)
        lines = np.matmul(M[v], plucker)                                             # (J, 3, N) in view v
        # Normalize so that x · l is a distance in view v's unit; l = 0 (same view) stays 0.
        lines *= (1.0 / unit[v]) / (np.sqrt(lines[:, 0] ** 2 + lines[:, 1] ** 2) + 1e-30)[:, None]
        d = np.matmul(points[:, rows], lines)                                        # (J, n_v, N)
        sums[rows] = np.abs(d, out=d).sum(axis=0)
    common = visible.astype(dtype) @ visible.T.astype(dtype)
    with np.errstate(divide="ignore", invalid="ignore"):
        D = (sums + sums.T) / (2 * common)
    undefined = (common < max(min_common_keypoints, 1)) | no_baseline[view[:, None], view[None, :]]
    D[undefined] = np.nan
    D[view[:, None] == view[None, :]] = np.inf
    return D


def appearance_similarity(appearance: np.ndarray | None, n: int, dtype=np.float32) -> np.ndarray | float:
    """Cosine similarity S of appearance descriptors, clipped to [0, 1].

    ``appearance: (N, D)`` or None -> ``(N, N)``, or the scalar 1.0 when descriptors are absent.
    """
    if appearance is None:
        return 1.0
    a = np.asarray(appearance, dtype=float)
    norm = np.linalg.norm(a, axis=1, keepdims=True)
    a = np.where(norm > 0, a / np.maximum(norm, 1e-12), 0.0).astype(dtype)
    return np.clip(a @ a.T, 0.0, 1.0)


def affinity(D: np.ndarray, gamma: float, S: np.ndarray | float = 1.0) -> np.ndarray:
    """Eq. 1: ``A = S / (1 + exp(γ D))``. ``D: (N, N)`` -> ``A: (N, N)`` in [0, 0.5]; D = inf
    gives 0 and an undefined D (NaN) stays NaN."""
    with np.errstate(over="ignore", invalid="ignore"):
        geometric = 1.0 / (1.0 + np.exp(np.minimum(gamma * D, 80.0)))
    return S * geometric


def mse_distance(keypoints: np.ndarray, view: np.ndarray, keypoint_threshold: float,
                 focal: np.ndarray, distance_scale: float, min_common_keypoints: int = 1) -> np.ndarray:
    """The paper's MSE baseline distance: mean squared 2D distance of common keypoints, in the
    same unit as :func:`epipolar_distance` (squared, then square-rooted). ``(N, N)``."""
    visible = keypoints[:, :, 2] >= max(keypoint_threshold, 1e-9)
    xy = keypoints[:, :, :2] / (distance_scale * focal[view])[:, None, None]
    xy = np.where(visible[..., None], xy, 0.0)
    sq = (xy**2).sum(-1)
    common = visible.astype(float) @ visible.T.astype(float)
    cross = np.einsum("ujd,vjd->uv", xy, xy)
    total = sq @ visible.T.astype(float) + visible.astype(float) @ sq.T - 2 * cross
    with np.errstate(divide="ignore", invalid="ignore"):
        D = np.sqrt(np.maximum(total, 0) / common)
    D[common < max(min_common_keypoints, 1)] = np.nan
    D[view[:, None] == view[None, :]] = np.inf
    return D
