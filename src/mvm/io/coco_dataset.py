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
from itertools import chain
from pathlib import Path

import numpy as np

from mvm.core.completion import FLAG_NAMES, MISSING, parse_flags
from mvm.core.keypoints import NUM_JOINTS
from mvm.errors import InputError
from mvm.io.checks import numbers
from mvm.io.coco import (
    CocoKeypoints,
    annotation_head,
    annotations_at_once,
    load_document,
    read_images,
    read_person,
    stack_appearance,
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
    data = load_document(path, root)
    image_ids, names, sizes = read_images(data["images"], path, allow_parent=True)
    index = {image_id: i for i, image_id in enumerate(image_ids)}
    columns = _dataset_at_once(data["annotations"], index)
    if columns is None:                      # something to report: the first problem, by name
        columns = _dataset_one_by_one(data["annotations"], path, index)
    ann_ids, ann_image, keypoints, scores, apps, crowd, boxes, depths, flags = columns
    people = CocoKeypoints(
        image_ids=np.array(image_ids, dtype=np.int64), file_names=tuple(names),
        sizes=np.array(sizes, dtype=float).reshape(-1, 2), ann_ids=np.array(ann_ids, dtype=np.int64),
        ann_image=np.array(ann_image, dtype=np.int64), keypoints=keypoints, score=np.array(scores, dtype=float),
        appearance=stack_appearance(apps, path))
    return CocoDataset(people, crowd, boxes, depths, flags, data)


def _dataset_one_by_one(annotations: list, path: Path, index: dict[int, int]) -> tuple:
    """The person annotations checked one at a time: ids, image indices, keypoints
    ``(N, 17, 3)``, scores, appearances (None each where absent), crowd ``(N,)``, boxes
    ``(N, 4)``, depths ``(N, 17)`` and flags ``(N, 17)`` or None; the first problem raises
    :class:`InputError` naming its field."""
    seen: set[int] = set()
    rows: list[tuple] = []
    for i, ann in enumerate(annotations):
        field = f"annotations[{i}]"
        ann_id, image, category = annotation_head(ann, path, field, index, seen)
        if category != 1:
            continue
        crowd = _crowd(ann.get("iscrowd", 0), path, f"{field}.iscrowd")
        if crowd and "keypoints" not in ann:
            kp, score, app = np.zeros((NUM_JOINTS, 3)), 0.0, None
        else:
            kp, score, app = read_person(ann, path, field)
        rows.append((ann_id, image, kp, score, app, crowd, _box(ann.get("bbox"), path, f"{field}.bbox"),
                     _depths(ann, kp, path, field), _flags(ann.get("keypoint_flags"), path, f"{field}.keypoint_flags")))
    ann_ids, ann_image, kps, scores, apps, crowd, boxes, depths, flags = ((list(c) for c in zip(*rows)) if rows
                                                                          else [[]] * 9)
    N = len(rows)
    has_flags = any(f is not None for f in flags)
    return (ann_ids, ann_image, np.array(kps, dtype=float).reshape(N, NUM_JOINTS, 3), scores, apps,
            np.array(crowd, dtype=bool), np.array(boxes, dtype=float).reshape(N, 4),
            np.array(depths, dtype=float).reshape(N, NUM_JOINTS),
            np.array([np.full(NUM_JOINTS, MISSING, np.int8) if f is None else f for f in flags],
                     dtype=np.int8).reshape(N, NUM_JOINTS) if has_flags else None)


_ABSENT = object()
_NO_KEYPOINTS = [0] * (3 * NUM_JOINTS)
_FLAG_OF = {name: i for i, name in enumerate(FLAG_NAMES)}


def _dataset_at_once(annotations: list, index: dict[int, int]) -> tuple | None:
    """What :func:`_dataset_one_by_one` returns, with every check done on all annotations at
    once (:func:`mvm.io.coco.annotations_at_once` and array operations: a COCO training set
    holds hundreds of thousands); None where any check fails, for the one-by-one reading to
    name the first problem."""
    prepared = [{**ann, "keypoints": _NO_KEYPOINTS, "score": 0, "appearance": None}
                if type(ann) is dict and "keypoints" not in ann and ann.get("iscrowd") else ann for ann in annotations]
    columns = annotations_at_once(prepared, index)
    if columns is None:
        return None
    people = [ann for ann in annotations if ann.get("category_id", 1) == 1]
    kp = columns[2]
    crowd = [ann.get("iscrowd", 0) for ann in people]
    if not all(type(c) in (int, bool) and c in (0, 1) for c in crowd):
        return None
    boxes = _rows_at_once([ann.get("bbox") for ann in people], 4)
    if boxes is None:
        return None
    with np.errstate(invalid="ignore"):
        degenerate = ~((boxes[:, 2] > 0) & (boxes[:, 3] > 0) & np.isfinite(boxes[:, :2] + boxes[:, 2:]).all(1))
    boxes[:, 2:] += boxes[:, :2]
    boxes[degenerate] = np.nan
    depths = _depths_at_once(people, kp)
    flags = _flags_at_once([ann.get("keypoint_flags") for ann in people])
    if depths is None or flags is False:
        return None
    return (*columns, np.array(crowd, dtype=bool), boxes, depths, flags)


def _rows_at_once(values: list, n: int) -> np.ndarray | None:
    """``values`` (lists of ``n`` numbers, or None: absent) -> ``(N, n)``, NaN rows where
    absent; None where any present value is not ``n`` finite numbers."""
    present = [k for k, v in enumerate(values) if v is not None]
    rows = [values[k] for k in present]
    if not all(type(v) is list and len(v) == n for v in rows):
        return None
    if rows and not set(map(type, chain.from_iterable(rows))) <= {float, int}:
        return None
    out = np.full((len(values), n), np.nan)
    if rows:
        try:
            out[present] = np.array(rows, dtype=float)
        except OverflowError:
            return None
        if not np.isfinite(out[present]).all():
            return None
    return out


def _depths_at_once(people: list, kp: np.ndarray) -> np.ndarray | None:
    """:func:`_depths` of every annotation of ``people`` (keypoints ``kp: (N, 17, 3)``) ->
    ``(N, 17)``; None where any is not plain."""
    values = [ann.get("keypoint_depths", _ABSENT) for ann in people]
    if all(v is _ABSENT for v in values):
        return np.full((len(people), NUM_JOINTS), np.nan)
    if any(v is None for v in values):
        return None
    d = _rows_at_once([None if v is _ABSENT else v for v in values], NUM_JOINTS)
    if d is None or (d < 0).any():
        return None
    flags = [ann.get("has_3d", _ABSENT) for ann in people]
    given = [k for k, v in enumerate(flags) if v is not _ABSENT]
    if not all(type(flags[k]) is list and len(flags[k]) == NUM_JOINTS for k in given):
        return None
    if not all(type(v) in (int, bool) and v in (0, 1) for k in given for v in flags[k]):
        return None
    with np.errstate(invalid="ignore"):
        has = d > 0
        has[given] = np.array([flags[k] for k in given], dtype=bool).reshape(-1, NUM_JOINTS)
        return np.where(has & (d > 0) & (kp[..., 2] > 0), d, np.nan)


def _flags_at_once(values: list):
    """:func:`_flags` of every annotation -> ``(N, 17)`` int8 (``MISSING`` where absent), None
    where none has flags, False where any is not 17 known names."""
    if all(v is None for v in values):
        return None
    out = np.full((len(values), NUM_JOINTS), MISSING, dtype=np.int8)
    for k, names in enumerate(values):
        if names is None:
            continue
        if type(names) is not list or len(names) != NUM_JOINTS:
            return False
        try:
            out[k] = [_FLAG_OF[name] for name in names]
        except (KeyError, TypeError):
            return False
    return out


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
