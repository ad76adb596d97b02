"""COCO keypoint data sets for training and evaluation: COCO 2017 (crowds, people annotated
without keypoints, boxes) and mvm's supervision sets (:mod:`mvm.net.supervision`), whose
annotations may carry per-keypoint fields:

- ``keypoint_depths``: 17 relative depths (camera z over the image's reference z), 0 where missing;
- ``has_3d``: 17 flags (0/1), whether each depth is a target (default: the depth is > 0);
- ``keypoint_flags``: 17 names (:data:`mvm.core.completion.FLAG_NAMES`): how each 3D joint was
  obtained.

The checks are those of :mod:`mvm.io.coco` (the same messages), plus these fields'. A
``file_name`` is relative; it may climb above the file's folder with ``..`` (an export with
``--link none`` and a merged set name the frames where they are, relative to the set).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.core.completion import FLAG_NAMES, MISSING, parse_flags
from mvm.core.keypoints import NUM_JOINTS
from mvm.errors import InputError
from mvm.io.checks import numbers
from mvm.io.coco import (
    CocoKeypoints,
    _annotation_head,
    _load_document,
    _person,
    _read_images,
    _stack_appearance,
)


@dataclass(frozen=True)
class CocoDataset:
    """A COCO keypoints data set.

    Attributes:
        people: the images and the person annotations (:class:`mvm.io.coco.CocoKeypoints`;
            ``N`` annotations, a crowd without keypoints has none present).
        crowd: ``(N,)`` whether the annotation is a crowd (``iscrowd``).
        boxes: ``(N, 4)`` ``bbox`` as ``x0, y0, x1, y1``; NaN where absent or of no area.
        depths: ``(N, 17)`` relative depths where ``has_3d`` and the keypoint is present, else NaN.
        flags: ``(N, 17)`` int8 joint flags (``MISSING`` where an annotation has none), or None
            when no annotation has ``keypoint_flags``.
        document: the parsed file (for tools that take COCO dicts, e.g. pycocotools).
    """

    people: CocoKeypoints
    crowd: np.ndarray
    boxes: np.ndarray
    depths: np.ndarray
    flags: np.ndarray | None
    document: dict


def read_coco_dataset(path: str | Path, root: str | Path | None = None) -> CocoDataset:
    """Read and validate a COCO keypoints data set; any problem raises one ``InputError`` line
    naming the file and the field. With ``root``, the file must lie inside that folder
    (:func:`mvm.io.checks.read_bytes`)."""
    path = Path(path)
    data = _load_document(path, root)
    image_ids, names, sizes = _read_images(data["images"], path, allow_parent=True)
    index = {image_id: i for i, image_id in enumerate(image_ids)}
    seen: set[int] = set()
    rows: list[tuple] = []
    for i, ann in enumerate(data["annotations"]):
        field = f"annotations[{i}]"
        ann_id, image, category = _annotation_head(ann, path, field, index, seen)
        if category != 1:
            continue
        crowd = _crowd(ann.get("iscrowd", 0), path, f"{field}.iscrowd")
        if crowd and "keypoints" not in ann:
            kp, score, app = np.zeros((NUM_JOINTS, 3)), 0.0, None
        else:
            kp, score, app = _person(ann, path, field)
        rows.append((ann_id, image, kp, score, app, crowd, _box(ann.get("bbox"), path, f"{field}.bbox"),
                     _depths(ann, kp, path, field), _flags(ann.get("keypoint_flags"), path, f"{field}.keypoint_flags")))
    ann_ids, ann_image, kps, scores, apps, crowd, boxes, depths, flags = (list(c) for c in zip(*rows)) if rows else [[]] * 9
    N = len(rows)
    people = CocoKeypoints(
        image_ids=np.array(image_ids, dtype=np.int64), file_names=tuple(names),
        sizes=np.array(sizes, dtype=float).reshape(-1, 2), ann_ids=np.array(ann_ids, dtype=np.int64),
        ann_image=np.array(ann_image, dtype=np.int64), keypoints=np.array(kps, dtype=float).reshape(N, NUM_JOINTS, 3),
        score=np.array(scores, dtype=float), appearance=_stack_appearance(apps, path))
    has_flags = any(f is not None for f in flags)
    return CocoDataset(
        people=people, crowd=np.array(crowd, dtype=bool), boxes=np.array(boxes, dtype=float).reshape(N, 4),
        depths=np.array(depths, dtype=float).reshape(N, NUM_JOINTS),
        flags=np.array([np.full(NUM_JOINTS, MISSING, np.int8) if f is None else f for f in flags],
                       dtype=np.int8).reshape(N, NUM_JOINTS) if has_flags else None,
        document=data)


def _crowd(value, path: Path, field: str) -> bool:
    """``iscrowd``: 0 or 1 (or a boolean)."""
    if not isinstance(value, (int, bool)) or value not in (0, 1):
        raise InputError(path, field, f"expected 0 or 1, got {repr(value)[:40]}")
    return bool(value)


def _box(bbox, path: Path, field: str) -> np.ndarray:
    """COCO ``[x, y, w, h]`` -> ``(4,)`` ``x0, y0, x1, y1``; NaN when absent or of no area."""
    if bbox is None:
        return np.full(4, np.nan)
    x, y, w, h = numbers(bbox, path, field, (4,), "4 numbers (x, y, width, height)")
    if not (w > 0 and h > 0 and np.isfinite([x + w, y + h]).all()):
        return np.full(4, np.nan)
    return np.array([x, y, x + w, y + h])


def _depths(ann: dict, kp: np.ndarray, path: Path, field: str) -> np.ndarray:
    """``(17,)`` the annotation's ``keypoint_depths`` where ``has_3d`` and the keypoint
    ``kp: (17, 3)`` is present, NaN elsewhere (all NaN without depths)."""
    if "keypoint_depths" not in ann:
        return np.full(NUM_JOINTS, np.nan)
    d = numbers(ann["keypoint_depths"], path, f"{field}.keypoint_depths", (NUM_JOINTS,))
    if (d < 0).any():
        j = int(np.flatnonzero(d < 0)[0])
        raise InputError(path, f"{field}.keypoint_depths[{j}]", f"negative depth {d[j]}")
    has = d > 0
    if "has_3d" in ann:
        value = ann["has_3d"]
        if not (isinstance(value, list) and len(value) == NUM_JOINTS
                and all(v in (0, 1) and isinstance(v, (int, bool)) for v in value)):
            raise InputError(path, f"{field}.has_3d", f"expected {NUM_JOINTS} flags 0 or 1")
        has = np.array(value, dtype=bool)
    return np.where(has & (d > 0) & (kp[:, 2] > 0), d, np.nan)


def _flags(value, path: Path, field: str) -> np.ndarray | None:
    """``keypoint_flags``: 17 names -> ``(17,)`` int8; None when absent."""
    if value is None:
        return None
    if not isinstance(value, list) or len(value) != NUM_JOINTS or not all(isinstance(n, str) for n in value):
        raise InputError(path, field, f"expected a list of {NUM_JOINTS} names ({', '.join(FLAG_NAMES)})")
    try:
        return parse_flags(value, field)
    except ValueError as e:
        raise InputError(path, field, str(e).split(": ", 1)[1]) from None
