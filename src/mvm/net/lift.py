"""Lifting the network's 2D keypoints and relative depths to 3D, and the length-scale calibration
of the lifted poses (Section 5 of the paper).

The network predicts relative depths, so a lifted pose is known up to scale: each pose is scaled
by the ``s*`` of its bones (:func:`mvm.core.keypoints.optimal_scale`).
"""
from __future__ import annotations

import numpy as np

from mvm.core.keypoints import MEAN_BONE_LENGTHS_M, bone_lengths, optimal_scale


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
