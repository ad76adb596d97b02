"""OpenPifPaf JSON predictions (``--json-output``): one file per frame holding a list of
``{"keypoints": [51 numbers], "bbox": [x, y, w, h], "score": float, "category_id": 1}``."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mvm.core.keypoints import NUM_JOINTS
from mvm.errors import InputError
from mvm.io.checks import load_json, number, numbers
from mvm.io.openpose import frame_files


def read_openpifpaf_frame(path: str | Path, root: str | Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Read one OpenPifPaf predictions file -> ``(K, 17, 3)`` keypoints (pixels, confidence;
    a missing joint is 0, 0, 0) and ``(K,)`` pose scores. Non-person categories are skipped.
    With ``root``, the file must lie inside it (:func:`mvm.io.checks.read_bytes`)."""
    path = Path(path)
    data = load_json(path, root)
    if not isinstance(data, list):
        raise InputError(path, None, "expected a JSON list of predictions")
    keypoints, scores = [], []
    for k, item in enumerate(data):
        if not isinstance(item, dict) or "keypoints" not in item:
            raise InputError(path, f"[{k}].keypoints", "missing")
        category = item.get("category_id", 1)
        if isinstance(category, bool) or not isinstance(category, int):
            raise InputError(path, f"[{k}].category_id", f"expected an integer, got {type(category).__name__}")
        if category != 1:
            continue
        kp = numbers(item["keypoints"], path, f"[{k}].keypoints", (3 * NUM_JOINTS,)).reshape(NUM_JOINTS, 3)
        kp[kp[:, 2] <= 0] = 0.0
        present = kp[:, 2] > 0
        default = float(kp[present, 2].mean()) if present.any() else 0.0
        score = number(item.get("score", default), path, f"[{k}].score")
        if score < 0:
            raise InputError(path, f"[{k}].score", f"negative score {score}")
        keypoints.append(kp)
        scores.append(score)
    K = len(keypoints)
    return np.array(keypoints, dtype=float).reshape(K, NUM_JOINTS, 3), np.array(scores, dtype=float)


def read_openpifpaf_dir(directory: str | Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Read every ``*.json`` predictions file of ``directory``: ``{frame number: (keypoints, scores)}``."""
    return {n: read_openpifpaf_frame(p) for n, p in frame_files(directory, "*.json")}
