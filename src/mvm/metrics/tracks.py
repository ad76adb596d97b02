"""How steady a tracked person is, without ground truth: a real body's bones keep their length,
and a person balancing or walking moves smoothly.

- **Limb-length std**: each bone's (:data:`mvm.core.keypoints.BONES`) standard deviation of its
  length over the instants of a track, then the mean over the bones. A perfect reconstruction
  gives 0; a detector's noise, a joint of the other side or a wrong association show up in it.
  Pose2Sim and the markerless-capture field report it on real captures where no ground truth exists.
- **Jitter**: the mean norm of each joint's second difference over consecutive instants (the
  acceleration times the frame interval squared), in the coordinates' unit per frame².

Tracks are ``(T, 17, 3)`` arrays, NaN where a joint is missing; instants are consecutive.
"""
from __future__ import annotations

import numpy as np

from mvm.core.keypoints import bone_lengths


def limb_length_std(track: np.ndarray, min_instants: int = 2) -> np.ndarray:
    """Each bone's standard deviation of its length over a track.

    ``track: (T, 17, 3)`` -> ``(12,)`` in the coordinates' unit, NaN for a bone with both ends
    present in fewer than ``min_instants`` instants.

    >>> track = np.zeros((3, 17, 3)); track[:, 7, 0] = [0.30, 0.32, 0.28]   # left elbow along x
    >>> round(float(limb_length_std(track)[0]), 4)
    0.02
    """
    lengths = bone_lengths(np.asarray(track, dtype=float))                 # (T, 12)
    count = np.isfinite(lengths).sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.nansum(lengths, 0) / count
        var = np.nansum((lengths - mean) ** 2, 0) / (count - 1)
    return np.where(count >= min_instants, np.sqrt(var), np.nan)


def jitter(track: np.ndarray) -> float:
    """Mean norm of the joints' second differences over consecutive instants: ``track: (T, 17,
    3)`` -> a length per frame², NaN for fewer than three instants or no joint present in three
    consecutive ones.

    >>> t = np.arange(5.0)[:, None, None] * np.ones((5, 17, 3))    # uniform motion: no jitter
    >>> jitter(t), round(jitter(t ** 2), 4)          # second differences of t²: 2 per axis
    (0.0, 3.4641)
    """
    track = np.asarray(track, dtype=float)
    if len(track) < 3:
        return float("nan")
    second = track[2:] - 2 * track[1:-1] + track[:-2]                       # (T-2, 17, 3)
    norm = np.linalg.norm(second, axis=-1)
    return float(np.nanmean(norm)) if np.isfinite(norm).any() else float("nan")
