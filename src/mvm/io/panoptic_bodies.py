"""CMU Panoptic 3D bodies: ``body3DScene_*.json`` files of ``joints19`` (x, y, z in centimetres and a
confidence per joint), read as COCO-17 keypoints in metres."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mvm.core.keypoints import COCO_KEYPOINTS, NUM_JOINTS
from mvm.errors import InputError
from mvm.io.checks import load_json

#: Panoptic ``joints19`` order (the data set's documentation).
PANOPTIC_JOINTS19: tuple[str, ...] = (
    "neck", "nose", "body_centre", "left_shoulder", "left_elbow", "left_wrist", "left_hip",
    "left_knee", "left_ankle", "right_shoulder", "right_elbow", "right_wrist", "right_hip",
    "right_knee", "right_ankle", "left_eye", "left_ear", "right_eye", "right_ear",
)
#: For each COCO keypoint, its index in ``PANOPTIC_JOINTS19``.
PANOPTIC_TO_COCO17 = np.array([PANOPTIC_JOINTS19.index(name) for name in COCO_KEYPOINTS])


def read_panoptic_coco19(path: str | Path) -> np.ndarray:
    """One Panoptic ``body3DScene_*.json`` -> ``(bodies, 17, 3)`` metres in Panoptic's world axes (y down).

    Joints with a negative confidence (Panoptic's mark for "not reconstructed") are NaN.
    Bodies come in file order; their ids are given by ``read_panoptic_ids``.
    """
    bodies = _panoptic_bodies(Path(path))
    out = np.empty((len(bodies), NUM_JOINTS, 3))
    for i, joints in enumerate(bodies):
        xyz = joints[PANOPTIC_TO_COCO17, :3] / 100.0
        xyz[joints[PANOPTIC_TO_COCO17, 3] < 0] = np.nan
        out[i] = xyz
    return out


def read_panoptic_ids(path: str | Path) -> list[int]:
    """The ``id`` of every body of a Panoptic ``body3DScene_*.json``, in file order."""
    path = Path(path)
    data = _panoptic_json(path)
    return [_panoptic_id(body, path, i) for i, body in enumerate(data["bodies"])]


def _panoptic_json(path: Path) -> dict:
    data = load_json(path)
    if not isinstance(data, dict) or not isinstance(data.get("bodies"), list):
        raise InputError(path, "bodies", "missing, or not a list")
    return data


def _panoptic_id(body, path, i) -> int:
    if not isinstance(body, dict) or isinstance(body.get("id"), bool) or not isinstance(body.get("id"), int):
        raise InputError(path, f"bodies[{i}].id", "missing, or not an integer")
    return body["id"]


def _panoptic_bodies(path: Path) -> list[np.ndarray]:
    """``bodies[].joints19`` as ``(19, 4)`` arrays x, y, z (cm), confidence."""
    data = _panoptic_json(path)
    out = []
    for i, body in enumerate(data["bodies"]):
        field = f"bodies[{i}].joints19"
        values = body.get("joints19") if isinstance(body, dict) else None
        if not isinstance(values, list) or len(values) != 4 * len(PANOPTIC_JOINTS19):
            got = len(values) if isinstance(values, list) else type(values).__name__
            raise InputError(path, field, f"expected {4 * len(PANOPTIC_JOINTS19)} numbers "
                                          f"(19 joints × x, y, z, confidence), got {got}")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values):
            raise InputError(path, field, "expected finite numbers")
        out.append(np.asarray(values, dtype=float).reshape(len(PANOPTIC_JOINTS19), 4))
    return out
