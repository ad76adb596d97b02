"""The paper's quality metrics of a reconstruction, which need no ground truth (Table 1):
E_R (reprojection error of the inlier keypoints), outliers per 3D pose, |G_k| (inlier keypoints
per reconstructed joint). Pure numpy, no I/O."""
from __future__ import annotations

import numpy as np

from mvm.core.geometry import project


def reprojection_errors(X: np.ndarray, xy: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``X: (P, J, 3)``, ``xy: (P, M, J, 2)``, ``P: (P, M, 3, 4)`` -> errors ``(P, M, J)`` px.

    >>> P = np.hstack([np.eye(3), np.zeros((3, 1))])[None, None]          # 1 person, 1 view
    >>> X = np.array([[[0.0, 0.0, 1.0], [1.0, 1.0, 2.0]]])
    >>> reprojection_errors(X, np.array([[[[0.0, 0.0], [0.5, 0.0]]]]), P)
    array([[[0. , 0.5]]])
    """
    uv, _ = project(X[:, None], P)
    return np.linalg.norm(uv - xy, axis=-1)


def scene_quality(X: np.ndarray, errors: np.ndarray, inliers: np.ndarray, valid: np.ndarray,
                  n_poses: int, n_matched: int) -> dict:
    """The paper's Table-1 metrics of one scene.

    Args:
        X: ``(P, J, 3)`` (NaN: not reconstructed); errors: ``(P, M, J)`` reprojection errors;
        inliers, valid: ``(P, M, J)`` keypoints used / available; n_poses: 2D poses in the
        scene; n_matched: 2D poses in a reconstructed person.
    Returns:
        ``E_R_px`` mean error over the inlier keypoints; ``G_k`` mean inliers per reconstructed
        joint; ``outliers`` mean rejected keypoints per 3D pose; counts.
    """
    reconstructed = np.isfinite(X).all(-1)                               # (P, J)
    used = inliers & reconstructed[:, None, :]
    rejected = valid & ~inliers & reconstructed[:, None, :]
    P = len(X)
    return {
        "E_R_px": float(errors[used].mean()) if used.any() else float("nan"),
        "outliers": float(rejected.sum() / P) if P else float("nan"),
        "G_k": float(used.sum() / reconstructed.sum()) if reconstructed.any() else float("nan"),
        "persons": int(P),
        "matched_poses": int(n_matched),
        "unmatched_poses": int(n_poses - n_matched),
        "reconstructed_joints": int(reconstructed.sum()),
    }


def row_nanmedian(a: np.ndarray) -> np.ndarray:
    """``np.nanmedian(a, axis=1)`` of ``a: (Q, B)`` -> ``(Q,)``, NaN for an all-NaN row, with no
    warning, and the same numbers: the mean of the middle two of each row's sorted non-NaN
    values (NaNs sort last). For the few short rows of one scene, ``np.nanmedian`` goes through
    masked arrays and costs several times more.

    >>> row_nanmedian(np.array([[1.0, 5.0, 2.0], [4.0, np.nan, 3.0], [np.nan, np.nan, np.nan]]))
    array([2. , 3.5, nan])
    """
    s = np.sort(a, axis=1)
    n = (~np.isnan(a)).sum(1)
    rows = np.arange(len(s))
    lo = s[rows, np.maximum((n - 1) // 2, 0)]
    hi = s[rows, np.minimum(n // 2, a.shape[1] - 1)]
    return np.where(n > 0, (lo + hi) / 2, np.nan)


def row_nanquantile(a: np.ndarray, q: float) -> np.ndarray:
    """``np.nanquantile(a, q, axis=-1)`` (linear interpolation; NaN where a row has none),
    without its warnings, and vectorized: numpy's loops over the rows in Python (70 times
    slower on a chunk of pairs of persons).

    >>> [round(float(v), 3) for v in row_nanquantile(np.array([[0.1, np.nan, 0.2, 3.0, 0.3], [np.nan] * 5]), 0.75)]
    [0.975, nan]
    """
    n = (~np.isnan(a)).sum(-1)
    s = np.sort(np.where(np.isnan(a), np.inf, a), axis=-1)                   # the n values first
    pos = q * np.maximum(n - 1, 0)
    lo = np.floor(pos).astype(np.int64)
    below = np.take_along_axis(s, lo[..., None], -1)[..., 0]
    above = np.take_along_axis(s, np.minimum(lo + 1, np.maximum(n - 1, 0))[..., None], -1)[..., 0]
    with np.errstate(invalid="ignore"):
        return np.where(n > 0, below + (pos - lo) * (above - below), np.nan)
