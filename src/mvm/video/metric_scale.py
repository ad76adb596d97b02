"""Metric scale of a video's reconstruction from the people themselves (the paper's s*).

SfM is up to scale. With ``l_b`` the median length of bone ``b`` over the reconstructed
persons (model units) and ``l̄_b`` the average adult length (metres), ``s*``
(:func:`mvm.core.keypoints.optimal_scale`) is in metres per model unit. The median over persons
keeps one badly reconstructed person from moving it.
"""
from __future__ import annotations

import numpy as np

from mvm.core.keypoints import MEAN_BONE_LENGTHS_M, bone_lengths, optimal_scale


def people_scale(poses3d: np.ndarray, min_persons: int = 1) -> tuple[float, int]:
    """Metres per model unit from the persons' bones.

    ``poses3d: (P, 17, 3)`` model units (NaN: missing) -> ``(s*, bones used)``; ``s*`` is NaN
    when no bone is measured by at least ``min_persons`` persons.

    >>> from mvm.sim.people import STANDING
    >>> round(people_scale(STANDING[None] / 2.0)[0], 1)
    2.0
    """
    poses3d = np.asarray(poses3d, dtype=float)
    if poses3d.ndim != 3 or poses3d.shape[1:] != (17, 3):
        raise ValueError(f"poses3d: expected shape (P, 17, 3), got {poses3d.shape}")
    lengths = bone_lengths(poses3d)                                # (P, 12)
    measured = np.isfinite(lengths).sum(0) >= max(min_persons, 1)
    if not measured.any():
        return float("nan"), 0
    median = np.nanmedian(lengths[:, measured], axis=0)
    return float(optimal_scale(median, MEAN_BONE_LENGTHS_M[measured])), int(measured.sum())
