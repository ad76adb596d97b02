"""A bank of real 3D human poses (CMU motion capture and CMU Panoptic), shipped with the package.

The bank frame: metres, z up, the lowest ankle on z = 0 (COCO has no foot points; the soles
lie about 0.08 m lower), the pelvis (mid-hips) at x = y = 0, and the body facing +y: its
forward direction, the cross product of the hip axis (right hip -> left hip) and up, is +y,
so the person's left hand side is -x.

``scripts/build_pose_data.py`` rebuilds ``data/pose_bank.npz`` from the source data.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.core.keypoints import INDEX, LEFT_HIP, LEFT_SHOULDER, NUM_JOINTS, RIGHT_HIP, RIGHT_SHOULDER, pelvis
from mvm.core.shipped import read_arrays
from mvm.errors import InputError

LABELS: tuple[str, ...] = ("standing", "sitting", "crouching", "other")

#: Source axes -> bank axes (z up): y-up data (ASF/AMC) and y-down data (CMU Panoptic).
Z_UP_FROM_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
Z_UP_FROM_Y_DOWN = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

_LEFT_LEG = (INDEX["left_hip"], INDEX["left_knee"], INDEX["left_ankle"])
_RIGHT_LEG = (INDEX["right_hip"], INDEX["right_knee"], INDEX["right_ankle"])
_ANKLES = [INDEX["left_ankle"], INDEX["right_ankle"]]

# --- pose classes (``classify_poses``) --------------------------------------------------------
#: Standing: pelvis height above the ankles at least this fraction of the leg length (thigh + shank). [1]
STANDING_MIN_HIP_HEIGHT = 0.75
#: Standing: the straighter knee at least this angle (180° = straight leg). [deg]
STANDING_MIN_KNEE_DEG = 125.0
#: Sitting and crouching: the trunk's elevation (pelvis -> mid-shoulders) at least this
#: much above the horizontal. [deg]
UPRIGHT_MIN_TRUNK_DEG = 45.0
#: Sitting: both thighs within this angle of the horizontal (hips about at knee height). [deg]
SITTING_MAX_THIGH_DEG = 35.0
#: Sitting: pelvis height above the ankles below this fraction of the leg length. [1]
SITTING_MAX_HIP_HEIGHT = 0.70
#: Sitting: the straighter knee opened at least this much (a deep squat, whose thighs are
#: horizontal too, closes both knees further). [deg]
SITTING_MIN_KNEE_DEG = 65.0
#: Crouching: pelvis height below this fraction of the leg length. [1]
CROUCHING_MAX_HIP_HEIGHT = 0.60
#: Crouching: both knees bent to at most this angle. [deg]
CROUCHING_MAX_KNEE_DEG = 120.0


@dataclass(frozen=True)
class PoseBank:
    """Real 3D poses in the bank frame.

    Attributes:
        poses: ``(B, 17, 3)`` float32 metres, COCO order; NaN where the source lacks a joint
            (a few Panoptic bodies); ``complete`` marks the poses without NaN.
        labels: ``(B,)`` str, one of ``LABELS``.
        sources: ``(B,)`` str: ``"01_02:360"`` (CMU motion 01_02, frame 360, 1-based at 120 fps)
            or ``"panoptic:000168:1"`` (Panoptic frame 168, body id 1).
    """

    poses: np.ndarray
    labels: np.ndarray
    sources: np.ndarray

    def __post_init__(self):
        b = len(self.poses)
        if self.poses.shape != (b, NUM_JOINTS, 3) or self.labels.shape != (b,) or self.sources.shape != (b,):
            raise ValueError(f"expected poses (B, 17, 3), labels (B,), sources (B,), got "
                             f"{self.poses.shape}, {self.labels.shape}, {self.sources.shape}")
        unknown = set(self.labels.tolist()) - set(LABELS)
        if unknown:
            raise ValueError(f"unknown labels {sorted(unknown)}; known: {', '.join(LABELS)}")

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def complete(self) -> np.ndarray:
        """``(B,)`` bool: poses with all 17 joints."""
        return ~np.isnan(self.poses).any(axis=(1, 2))

    def subset(self, mask_or_indices) -> PoseBank:
        """The bank restricted to a boolean mask ``(B,)`` or an index array."""
        return PoseBank(self.poses[mask_or_indices], self.labels[mask_or_indices], self.sources[mask_or_indices])

    def with_label(self, label: str) -> PoseBank:
        if label not in LABELS:
            raise ValueError(f"unknown label {label!r}; known: {', '.join(LABELS)}")
        return self.subset(self.labels == label)


def load_pose_bank(path: str | Path | None = None) -> PoseBank:
    """Read a pose bank ``.npz`` (default: the one shipped in ``mvm/data``)."""
    arrays = read_arrays(path, "pose_bank.npz", ("poses", "labels", "sources"), "a pose bank")
    try:
        return PoseBank(arrays["poses"].astype(np.float32), arrays["labels"].astype(str), arrays["sources"].astype(str))
    except ValueError as e:
        raise InputError(path or "mvm/data/pose_bank.npz", None, str(e)) from None


# --- building the bank (pure functions, used by scripts/build_pose_data.py) ----------------

def forward_direction(poses: np.ndarray) -> np.ndarray:
    """Horizontal facing direction. ``poses: (..., 17, 3)`` z up -> ``(..., 2)`` unit xy (NaN if undefined).

    Forward = (left hip - right hip) × up, i.e. ``(hy, -hx)`` for the hip axis ``h``.

    >>> pose = np.zeros((17, 3))
    >>> pose[LEFT_HIP, :2], pose[RIGHT_HIP, :2] = [0.0, 0.1], [0.0, -0.1]     # hips along y: facing +x
    >>> forward_direction(pose)
    array([ 1., -0.])
    """
    hip_axis = poses[..., LEFT_HIP, :2] - poses[..., RIGHT_HIP, :2]
    forward = np.stack([hip_axis[..., 1], -hip_axis[..., 0]], axis=-1)
    norm = np.linalg.norm(forward, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norm > 1e-9, forward / norm, np.nan)


def to_bank_frame(poses: np.ndarray) -> np.ndarray:
    """Rotate about z and translate z-up poses into the bank frame. ``poses: (P, 17, 3)`` -> ``(P, 17, 3)``.

    Poses without both hips or without any ankle come back all NaN.
    """
    poses = np.asarray(poses, dtype=float)
    f = forward_direction(poses)                                      # (P, 2) = (sin a, cos a) of the turn
    # rotate by the angle that takes f to +y: x' = fy x - fx y, y' = fx x + fy y
    rot = np.zeros(poses.shape[:-2] + (3, 3))
    rot[..., 0, 0], rot[..., 0, 1] = f[..., 1], -f[..., 0]
    rot[..., 1, 0], rot[..., 1, 1] = f[..., 0], f[..., 1]
    rot[..., 2, 2] = 1.0
    centre = pelvis(poses)
    with np.errstate(invalid="ignore"):
        out = np.einsum("...ij,...kj->...ki", rot, poses - centre[..., None, :] * np.array([1.0, 1.0, 0.0]))
    ankle_z = out[..., _ANKLES, 2]
    ground = np.min(np.where(np.isnan(ankle_z), np.inf, ankle_z), axis=-1)
    out[..., 2] -= ground[..., None]
    bad = ~np.isfinite(ground) | np.isnan(centre).any(axis=-1) | np.isnan(f).any(axis=-1)
    out[bad] = np.nan
    return out


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between vectors ``(..., 3)`` in degrees."""
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def pose_features(poses: np.ndarray) -> dict[str, np.ndarray]:
    """Features of z-up poses used by ``classify_poses``. ``poses: (P, 17, 3)`` -> dict of ``(P,)``.

    ``hip_height``: pelvis height above the lowest ankle / mean leg length; ``knee_max``,
    ``knee_min``: knee angles (deg, 180 = straight); ``thigh_max``: the steeper thigh's angle to
    the horizontal (deg); ``trunk``: elevation of pelvis -> mid-shoulders (deg, 90 = upright).
    """
    poses = np.asarray(poses, dtype=float)
    knees, thighs, legs = [], [], []
    for hip, knee, ankle in (_LEFT_LEG, _RIGHT_LEG):
        thigh = poses[..., hip, :] - poses[..., knee, :]
        shank = poses[..., ankle, :] - poses[..., knee, :]
        knees.append(_angle_deg(thigh, shank))
        thighs.append(np.degrees(np.arcsin(np.clip(thigh[..., 2] / np.linalg.norm(thigh, axis=-1), -1, 1))))
        legs.append(np.linalg.norm(thigh, axis=-1) + np.linalg.norm(shank, axis=-1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # all-NaN slices give NaN features
        leg = np.nanmean(np.stack(legs), axis=0)
        ground = np.nanmin(poses[..., _ANKLES, 2], axis=-1)
        knee_max = np.nanmax(np.stack(knees), axis=0)
        knee_min = np.nanmin(np.stack(knees), axis=0)
        thigh_max = np.nanmax(np.abs(np.stack(thighs)), axis=0)
    trunk_vec = 0.5 * (poses[..., LEFT_SHOULDER, :] + poses[..., RIGHT_SHOULDER, :]) - pelvis(poses)
    trunk = np.degrees(np.arcsin(np.clip(trunk_vec[..., 2] / np.linalg.norm(trunk_vec, axis=-1), -1, 1)))
    return {"hip_height": (pelvis(poses)[..., 2] - ground) / leg, "knee_max": knee_max,
            "knee_min": knee_min, "thigh_max": thigh_max, "trunk": trunk}


def classify_poses(poses: np.ndarray) -> np.ndarray:
    """Label z-up poses 'standing', 'sitting', 'crouching' or 'other'. ``poses: (P, 17, 3)`` -> ``(P,)`` str.

    Standing: trunk upright, pelvis high (``STANDING_MIN_HIP_HEIGHT``) and one leg nearly
    straight. Sitting: trunk upright, thighs near horizontal, pelvis low, knees not closed as in
    a squat. Crouching: trunk upright, pelvis low and both knees bent. Poses lacking the joints a
    rule needs are 'other'. The thresholds are the module constants above.
    """
    with np.errstate(invalid="ignore", all="ignore"):
        f = pose_features(poses)
        upright = f["trunk"] >= UPRIGHT_MIN_TRUNK_DEG
        standing = upright & (f["hip_height"] >= STANDING_MIN_HIP_HEIGHT) & (f["knee_max"] >= STANDING_MIN_KNEE_DEG)
        sitting = (upright & (f["thigh_max"] <= SITTING_MAX_THIGH_DEG) & (f["hip_height"] < SITTING_MAX_HIP_HEIGHT)
                   & (f["knee_max"] >= SITTING_MIN_KNEE_DEG))
        crouching = (upright & (f["hip_height"] < CROUCHING_MAX_HIP_HEIGHT)
                     & (f["knee_max"] <= CROUCHING_MAX_KNEE_DEG))
    labels = np.full(len(poses), "other", dtype="<U9")
    labels[crouching] = "crouching"
    labels[sitting] = "sitting"
    labels[standing] = "standing"
    return labels


def select_distinct(poses: np.ndarray, min_distance: float, chunk: int = 64) -> np.ndarray:
    """Greedy diverse subset: indices of poses far from every pose kept before them.

    ``poses: (N, 17, 3)`` in the bank frame -> ``(K,)`` increasing indices. Pose ``i`` is kept
    when its mean joint distance (metres, over the joints both poses have) to every pose kept
    so far is at least ``min_distance``; the first pose is always kept. ``chunk`` poses are
    compared with the kept ones at once (the result does not depend on it).
    """
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 3 or poses.shape[1:] != (NUM_JOINTS, 3):
        raise ValueError(f"expected poses (N, 17, 3), got {poses.shape}")
    kept = np.empty_like(poses)
    indices: list[int] = []
    for start in range(0, len(poses), chunk):
        block = poses[start:start + chunk]
        n_before = len(indices)
        far = _mean_distances(block, kept[:n_before]).min(axis=1, initial=np.inf) >= min_distance
        for j in np.flatnonzero(far):
            n = len(indices)
            if n == n_before or _mean_distances(block[j:j + 1], kept[n_before:n]).min() >= min_distance:
                kept[n] = block[j]
                indices.append(start + j)
    return np.array(indices, dtype=int)


def _mean_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean joint distance of every pair. ``a: (M, 17, 3)``, ``b: (K, 17, 3)`` -> ``(M, K)``."""
    d = np.sqrt(np.square(a[:, None] - b[None]).sum(axis=-1))
    if not np.isnan(d).any():
        return d.mean(axis=-1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # pairs without common joints give NaN
        out = np.nanmean(d, axis=-1)
    return np.where(np.isnan(out), np.inf, out)
