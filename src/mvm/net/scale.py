"""Length-scale calibration (Section 5 of the paper) and lifting of 2D + depth to 3D.

The network predicts relative depths, so a lifted pose is known up to scale. With the bone
lengths ``l_i`` of the lifted pose and average adult lengths ``l̄_i``, the scale minimizing
``Σ ½ (s·l_i − l̄_i)²`` is ``s* = Σ l̄_i l_i / Σ l_i²``.
"""
from __future__ import annotations

import numpy as np

from mvm.core.keypoints import MEAN_BONE_LENGTHS_M, bone_lengths


def optimal_scale(lengths: np.ndarray, mean_lengths: np.ndarray = MEAN_BONE_LENGTHS_M) -> np.ndarray:
    """``s* = Σ l̄_i l_i / Σ l_i²`` over the finite bones.

    ``lengths: (..., 12)`` (NaN: missing bone) -> ``(...)``; NaN where no bone is finite.

    >>> float(optimal_scale(np.array(MEAN_BONE_LENGTHS_M) / 2.0))
    2.0
    """
    l = np.asarray(lengths, dtype=float)
    mean = np.broadcast_to(np.asarray(mean_lengths, dtype=float), l.shape)
    ok = np.isfinite(l) & (l > 0)
    num = np.where(ok, mean * l, 0.0).sum(-1)
    den = np.where(ok, l * l, 0.0).sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / den, np.nan)


def lift(keypoints: np.ndarray, depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Back-project pixels at their depths: ``X = d · K⁻¹ [u, v, 1]``.

    ``keypoints: (P, 17, 2+)`` pixels (a third column > 0 marks present joints),
    ``depth: (P, 17)``, ``K: (3, 3)`` -> ``(P, 17, 3)`` camera coordinates, NaN where missing.
    """
    kp = np.asarray(keypoints, dtype=float)
    d = np.asarray(depth, dtype=float)
    rays = np.concatenate([kp[..., :2], np.ones(kp.shape[:-1] + (1,))], -1) @ np.linalg.inv(K).T
    X = rays * d[..., None]
    if kp.shape[-1] > 2:
        X[kp[..., 2] <= 0] = np.nan
    return X


def calibrate(points: np.ndarray, mean_lengths: np.ndarray = MEAN_BONE_LENGTHS_M) -> tuple[np.ndarray, np.ndarray]:
    """Scale every pose so its bones best match the average lengths.

    ``points: (P, 17, 3)`` in any unit -> metric points ``(P, 17, 3)`` and ``s* (P,)``.
    """
    s = optimal_scale(bone_lengths(points), mean_lengths)
    return points * s[:, None, None], s
