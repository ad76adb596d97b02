"""The 17 COCO keypoints: names, skeleton, left/right symmetry, body proportions and the metric
scale they give (the paper's s*).

Every array in mvm that has a joint axis uses this order (``J = 17``).
"""
from __future__ import annotations

import numpy as np

from mvm.core.quality import row_nanmedian

COCO_KEYPOINTS: tuple[str, ...] = (
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
)
NUM_JOINTS = len(COCO_KEYPOINTS)
INDEX = {name: i for i, name in enumerate(COCO_KEYPOINTS)}

#: The COCO person skeleton, 0-based joint index pairs (the COCO file lists them 1-based).
COCO_SKELETON: tuple[tuple[int, int], ...] = (
    (15, 13), (13, 11), (16, 14), (14, 12), (11, 12), (5, 11), (6, 12), (5, 6), (5, 7),
    (6, 8), (7, 9), (8, 10), (1, 2), (0, 1), (0, 2), (1, 3), (2, 4), (3, 5), (4, 6),
)

#: Bones of the body (no face connections), used for lengths and scale.
BONES: tuple[tuple[int, int], ...] = (
    (5, 7), (7, 9), (6, 8), (8, 10),          # arms
    (11, 13), (13, 15), (12, 14), (14, 16),   # legs
    (5, 6), (11, 12), (5, 11), (6, 12),       # torso
)

#: Average adult bone lengths in metres for ``BONES`` (anthropometric means, both sexes).
MEAN_BONE_LENGTHS_M = np.array(
    [0.29, 0.25, 0.29, 0.25,
     0.42, 0.41, 0.42, 0.41,
     0.35, 0.20, 0.50, 0.50]
)

#: Index permutation that swaps left and right joints (for horizontal flips).
FLIP_PERMUTATION = np.array([0, 2, 1, 4, 3, 6, 5, 8, 7, 10, 9, 12, 11, 14, 13, 16, 15])

#: Per-keypoint OKS sigmas of the COCO evaluation.
COCO_SIGMAS = np.array(
    [0.026, 0.025, 0.025, 0.035, 0.035, 0.079, 0.079, 0.072, 0.072, 0.062, 0.062,
     0.107, 0.107, 0.087, 0.087, 0.089, 0.089]
)

#: The COCO person category as written into keypoint files.
COCO_PERSON_CATEGORY = {
    "id": 1,
    "name": "person",
    "supercategory": "person",
    "keypoints": list(COCO_KEYPOINTS),
    "skeleton": [[a + 1, b + 1] for a, b in COCO_SKELETON],
}

LEFT_HIP, RIGHT_HIP = INDEX["left_hip"], INDEX["right_hip"]
LEFT_SHOULDER, RIGHT_SHOULDER = INDEX["left_shoulder"], INDEX["right_shoulder"]


def pelvis(points: np.ndarray) -> np.ndarray:
    """Mid-point of the hips. ``points: (..., 17, D)`` -> ``(..., D)``.

    >>> X = np.zeros((17, 3))
    >>> X[LEFT_HIP], X[RIGHT_HIP] = [0.2, 0.0, 1.0], [-0.2, 0.0, 1.0]
    >>> pelvis(X)
    array([0., 0., 1.])
    """
    return 0.5 * (points[..., LEFT_HIP, :] + points[..., RIGHT_HIP, :])


def bone_lengths(points: np.ndarray) -> np.ndarray:
    """Lengths of ``BONES``. ``points: (..., 17, D)`` -> ``(..., 12)`` (NaN where a joint is NaN).

    >>> X = np.zeros((17, 3))
    >>> X[INDEX["left_shoulder"]], X[INDEX["left_elbow"]] = [0.0, 0.0, 1.5], [0.0, 0.0, 1.25]
    >>> float(bone_lengths(X)[BONES.index((5, 7))])
    0.25
    >>> X[INDEX["left_wrist"]] = np.nan
    >>> bool(np.isnan(bone_lengths(X)[BONES.index((7, 9))]))
    True
    """
    points = np.asarray(points, dtype=float)
    a = points[..., [b[0] for b in BONES], :]
    b = points[..., [b[1] for b in BONES], :]
    return np.linalg.norm(a - b, axis=-1)


def optimal_scale(lengths: np.ndarray, mean_lengths: np.ndarray = MEAN_BONE_LENGTHS_M) -> np.ndarray:
    """The scale that best matches bone lengths to the mean adult ones (the paper's Eq. scale):
    ``s* = Σ l̄_b l_b / Σ l_b²`` over the finite bones of positive length, the minimum of
    ``Σ_b ½ (s l_b − l̄_b)²``.

    ``lengths: (..., B)`` (NaN: missing bone), ``mean_lengths: (B,)`` (default the ``12`` of
    :data:`MEAN_BONE_LENGTHS_M`) -> ``(...)``; NaN where no bone is finite.

    >>> float(optimal_scale(MEAN_BONE_LENGTHS_M / 2.0))
    2.0
    """
    l = np.asarray(lengths, dtype=float)
    mean = np.broadcast_to(np.asarray(mean_lengths, dtype=float), l.shape)
    ok = np.isfinite(l) & (l > 0)
    num = np.where(ok, mean * l, 0.0).sum(-1)
    den = np.where(ok, l * l, 0.0).sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / den, np.nan)


def bone_ratios(X: np.ndarray) -> np.ndarray:
    """Each bone's length over its human proportion at the person's own scale: ``l / (s · l_mean)``,
    ``s`` the median of ``l / l_mean`` over the person's bones (any unit, any posture: about
    1 ± 0.05 for a real person). ``X: (Q, J, 3)`` -> ``(Q, B)`` (NaN: a bone not reconstructed).

    >>> rng = np.random.default_rng(0)
    >>> X = rng.normal(size=(1, 17, 3))
    >>> A = bone_ratios(X)
    >>> np.allclose(bone_ratios(7.0 * X), A)       # the same in any unit
    True
    """
    ratio = bone_lengths(X) / MEAN_BONE_LENGTHS_M                               # (Q, B)
    with np.errstate(invalid="ignore", divide="ignore"):                    # a zero-length skeleton
        return ratio / row_nanmedian(ratio)[:, None]


def stray_joints(X: np.ndarray, max_ratio: float) -> np.ndarray:
    """``(Q, J)`` bool: the joints whose bones are all more than ``max_ratio`` times their
    proportion at the person's scale (:func:`bone_ratios`) — a joint whose keypoints agree with a
    point far along their rays (few views on a narrow arc, a keypoint of the other side among
    them). A joint of one bone (a wrist, an ankle) is blamed only where the bone's other joint
    is not: an elbow far off makes the forearm long too. ``X: (Q, J, 3)``.

    >>> X = np.zeros((1, 17, 3)); X[0, :, 0] = np.arange(17) * 0.02; X[0, 10, 1] = 9.0
    >>> np.flatnonzero(stray_joints(X, 3.0)[0]).tolist()
    [10]
    """
    ends = np.array(BONES)                                                  # (B, 2)
    touch = np.zeros((2, len(ends), X.shape[1]))                            # each bone's end joints
    touch[0, np.arange(len(ends)), ends[:, 0]] = touch[1, np.arange(len(ends)), ends[:, 1]] = 1.0
    with np.errstate(invalid="ignore"):
        ratio = bone_ratios(X)                                              # (Q, B)
    known, long = np.isfinite(ratio).astype(float), (ratio > max_ratio).astype(float)
    bones, bad = known @ touch.sum(0), long @ touch.sum(0)                  # (Q, J) each
    stray = (bones >= 2) & (bad == bones)
    for e in (0, 1):
        leaf = long * (bones[:, ends[:, e]] == 1) * ~stray[:, ends[:, 1 - e]]  # (Q, B)
        stray |= leaf @ touch[e] > 0
    return stray
