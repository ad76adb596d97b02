"""Joint angles of COCO-17 skeletons: the flexion of the knees, hips and elbows, from 3D joints.
Arrays in, arrays out.

The flexion at joint ``b`` of the chain ``a - b - c`` is ``180° - ∠abc``: 0° for a straight
limb, 90° for a right angle. It is unsigned (a bent and an over-stretched joint at the same
angle read the same) and needs no body frame, so it is defined on any pose, whatever its
orientation:

- knee: hip - knee - ankle;
- hip: shoulder - hip - knee (the thigh against the trunk's side);
- elbow: shoulder - elbow - wrist.
"""
from __future__ import annotations

import numpy as np

from mvm.core.keypoints import INDEX

#: The angles, in order: name -> the joints ``a``, ``b`` (the vertex), ``c`` of each.
JOINT_ANGLES: dict[str, tuple[str, str, str]] = {
    f"{side} {joint}": tuple(f"{side}_{j}" for j in chain)
    for joint, chain in (("knee", ("hip", "knee", "ankle")), ("hip", ("shoulder", "hip", "knee")),
                         ("elbow", ("shoulder", "elbow", "wrist")))
    for side in ("left", "right")
}
#: ``(A, 3)`` COCO indices of ``a``, ``b``, ``c`` of every angle of :data:`JOINT_ANGLES`.
ANGLE_JOINTS = np.array([[INDEX[n] for n in chain] for chain in JOINT_ANGLES.values()], dtype=np.int64)


def flexion_angles(X: np.ndarray, min_length: float = 1e-9) -> np.ndarray:
    """The flexion angles of :data:`JOINT_ANGLES` in degrees.

    ``X: (..., 17, 3)`` joints (NaN: missing) -> ``(..., A)``, NaN where one of the three joints
    is missing or a segment is shorter than ``min_length`` (in the units of ``X``).

    A straight left leg, a left knee bent at a right angle:

    >>> X = np.zeros((17, 3))
    >>> X[INDEX["left_hip"]], X[INDEX["left_knee"]], X[INDEX["left_ankle"]] = [0, 0, 1.0], [0, 0, 0.5], [0, 0, 0.0]
    >>> float(flexion_angles(X)[list(JOINT_ANGLES).index("left knee")])
    0.0
    >>> X[INDEX["left_ankle"]] = [0.5, 0, 0.5]
    >>> float(flexion_angles(X)[list(JOINT_ANGLES).index("left knee")])
    90.0
    """
    X = np.asarray(X, dtype=float)
    if X.shape[-2:] != (17, 3):
        raise ValueError(f"X: expected shape (..., 17, 3), got {X.shape}")
    a, b, c = (X[..., ANGLE_JOINTS[:, k], :] for k in range(3))            # (..., A, 3) each
    u, v = a - b, c - b
    nu, nv = np.linalg.norm(u, axis=-1), np.linalg.norm(v, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.einsum("...i,...i->...", u, v) / (nu * nv)
        included = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return np.where((nu > min_length) & (nv > min_length), 180.0 - included, np.nan)


def angle_sources(flags: np.ndarray) -> np.ndarray:
    """The least-observed flag among the three joints of each angle (the largest flag code of
    :mod:`mvm.core.completion`: missing 0, observed 1, interpolated 2, inferred 3, where missing
    wins). ``flags: (..., 17)`` int -> ``(..., A)``."""
    f = np.asarray(flags, dtype=np.int64)[..., ANGLE_JOINTS]                 # (..., A, 3)
    return np.where((f == 0).any(-1), 0, f.max(-1))
