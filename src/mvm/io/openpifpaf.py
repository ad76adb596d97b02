"""OpenPifPaf JSON predictions (``--json-output``): one file per frame holding a list of
``{"keypoints": [51 numbers], "bbox": [x, y, w, h], "score": float, "category_id": 1}``."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..keypoints import NUM_JOINTS
from .openpose import _load_json, frame_files


def read_openpifpaf_frame(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read one OpenPifPaf predictions file -> ``(K, 17, 3)`` keypoints (pixels, confidence;
    a missing joint is 0, 0, 0) and ``(K,)`` pose scores. Non-person categories are skipped."""
    path = Path(path)
    data = _load_json(path)
    if not isinstance(data, list):
        raise InputError(path, None, "expected a JSON list of predictions")
    keypoints, scores = [], []
    for k, item in enumerate(data):
        if not isinstance(item, dict) or "keypoints" not in item:
            raise InputError(path, f"[{k}].keypoints", "missing")
        if item.get("category_id", 1) != 1:
            continue
        try:
            kp = np.asarray(item["keypoints"], dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise InputError(path, f"[{k}].keypoints", "expected a list of numbers") from None
        if len(kp) != 3 * NUM_JOINTS:
            raise InputError(path, f"[{k}].keypoints", f"expected {3 * NUM_JOINTS} numbers, got {len(kp)}")
        if not np.isfinite(kp).all():
            raise InputError(path, f"[{k}].keypoints", "not finite")
        kp = kp.reshape(NUM_JOINTS, 3)
        kp[kp[:, 2] <= 0] = 0.0
        present = kp[:, 2] > 0
        default = float(kp[present, 2].mean()) if present.any() else 0.0
        score = item.get("score", default)
        if not isinstance(score, (int, float)) or not np.isfinite(score):
            raise InputError(path, f"[{k}].score", f"expected a number, got {score!r}")
        keypoints.append(kp)
        scores.append(float(score))
    K = len(keypoints)
    return np.array(keypoints, dtype=float).reshape(K, NUM_JOINTS, 3), np.array(scores, dtype=float)


def read_openpifpaf_dir(directory: str | Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Read every ``*.json`` predictions file of ``directory``: ``{frame number: (keypoints, scores)}``."""
    return {n: read_openpifpaf_frame(p) for n, p in frame_files(directory, "*.json")}
