"""COCO keypoint files (the *dataset* format: ``images``, ``annotations``, ``categories``), read
and written.

Two readers share one set of checks, every problem one :class:`~mvm.errors.InputError` line
naming the file and the field: the file is read the guarded way (:func:`mvm.io.checks.read_bytes`:
a regular file of bounded size); image ids and annotation ids are unique integers, an
annotation names an image of the file, keypoints are 51 finite numbers, scores finite and
not negative, file names relative (:mod:`mvm.io.paths`).

- :func:`read_coco_keypoints`: the 2D poses of a scene (``poses2d.json``), of a rig camera or
  of imported detections; a ``file_name`` must stay below its folder.
- :func:`read_coco_dataset`: a training or validation set, with crowds (``iscrowd``, possibly
  without keypoints), boxes, and the supervision fields ``keypoint_depths``, ``has_3d`` and
  ``keypoint_flags``; a ``file_name`` may climb above the file's folder (``--link none``
  exports and merged sets name the frames where they are).

The writers: :func:`coco_keypoints_document` (a scene's ``poses2d.json``),
:func:`annotation_record` and :func:`empty_dataset` (supervision data sets). COCO *results*
files are :mod:`mvm.io.coco_results`.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import chain
from pathlib import Path

import numpy as np

from mvm.core.completion import MISSING, flag_names
from mvm.core.keypoints import COCO_PERSON_CATEGORY, NUM_JOINTS
from mvm.errors import InputError
from mvm.io.checks import collector_paused, integer, load_json, number, numbers
from mvm.io.paths import check_name

SUPERVISION_FORMAT = "mvm.net.supervision/1"
"""``info.format`` of a supervision data set (:func:`empty_dataset`)."""


@dataclass(frozen=True)
class CocoKeypoints:
    """The content of a COCO keypoints file.

    Attributes:
        image_ids: ``(I,)``; file_names: ``I`` names; sizes: ``(I, 2)`` width, height (0 if absent).
        ann_ids: ``(N,)``; ann_image: ``(N,)`` index into the images (not the id);
        keypoints: ``(N, 17, 3)`` x, y, v with v in [0, 1] (COCO visibility flags 1 and 2 read as 1);
        score: ``(N,)``; appearance: ``(N, D)`` or None; info: the file's ``info`` object, or
        None (what made the poses: the detector, the video of a rig camera).
    """

    image_ids: np.ndarray
    file_names: tuple[str, ...]
    sizes: np.ndarray
    ann_ids: np.ndarray
    ann_image: np.ndarray
    keypoints: np.ndarray
    score: np.ndarray
    appearance: np.ndarray | None
    info: dict | None = None


def parse_keypoints(values, path, field) -> np.ndarray:
    """A flat list of 51 numbers -> ``(17, 3)`` with v in [0, 1]; coordinates of missing joints zeroed."""
    if not isinstance(values, list):
        raise InputError(path, field, f"expected a list of {3 * NUM_JOINTS} numbers, got {type(values).__name__}")
    kp = numbers(values, path, field, (3 * NUM_JOINTS,),
                 f"{3 * NUM_JOINTS} numbers (17 keypoints × x, y, v)").reshape(NUM_JOINTS, 3)
    if np.any(kp[:, 2] < 0):
        raise InputError(path, field, "negative keypoint confidence")
    return as_confidence(kp)


def as_confidence(keypoints: np.ndarray) -> np.ndarray:
    """COCO keypoints ``(..., 17, 3)`` (v >= 0), changed in place and returned: v clipped to 1
    (the ground-truth visibility flags 1 and 2 read as 1), a joint of v = 0 at 0, 0."""
    np.minimum(keypoints[..., 2], 1.0, out=keypoints[..., 2])
    keypoints[..., :2][keypoints[..., 2] == 0] = 0.0
    return keypoints


def _size(image: dict, key: str, path, field) -> float:
    """``width`` / ``height`` of an image: absent reads as 0 (unknown), present must be > 0."""
    if key not in image:
        return 0.0
    value = number(image[key], path, f"{field}.{key}")
    if value <= 0:
        raise InputError(path, f"{field}.{key}", f"must be > 0, got {image[key]!r}")
    return value


def read_coco_keypoints(path: str | Path, root: str | Path | None = None) -> CocoKeypoints:
    """Read and validate a COCO keypoints file; any problem raises one ``InputError`` line.

    ``file_name`` must be a relative name that stays below its folder (no absolute path, no
    ``..`` leading out): see :mod:`mvm.io.paths`. With ``root``, the file itself must lie
    inside that folder once its links are resolved (:func:`mvm.io.checks.read_bytes`).
    """
    path = Path(path)
    with collector_paused():
        return _read_keypoints(path, load_document(path, root))


def _read_keypoints(path: Path, data: dict) -> CocoKeypoints:
    """:func:`read_coco_keypoints` of the parsed document ``data``."""
    image_ids, names, sizes = read_images(data["images"], path)
    index = {image_id: i for i, image_id in enumerate(image_ids)}
    columns = annotations_at_once(data["annotations"], index)
    if columns is None:                      # something to report: the first problem, by name
        columns = _annotations_one_by_one(data["annotations"], path, index)
    ann_ids, ann_image, keypoints, scores, apps = columns
    return CocoKeypoints(
        image_ids=np.array(image_ids, dtype=np.int64),
        file_names=tuple(names),
        sizes=np.array(sizes, dtype=float).reshape(-1, 2),
        ann_ids=np.array(ann_ids, dtype=np.int64),
        ann_image=np.array(ann_image, dtype=np.int64),
        keypoints=keypoints,
        score=np.array(scores, dtype=float),
        appearance=stack_appearance(apps, path),
        info=data["info"] if isinstance(data.get("info"), dict) else None,
    )


def load_document(path: Path, root) -> dict:
    """The parsed COCO file ``path``: an object with the lists ``images`` and ``annotations``."""
    data = load_json(path, root)
    if not isinstance(data, dict):
        raise InputError(path, None, "expected a JSON object with 'images' and 'annotations'")
    for key in ("images", "annotations"):
        if not isinstance(data.get(key), list):
            raise InputError(path, key, "missing, or not a list")
    return data


def _annotations_one_by_one(annotations: list, path: Path, index: dict[int, int]) -> tuple:
    """The person annotations checked one at a time (:func:`_read_annotation`): ids, image
    indices, keypoints ``(N, 17, 3)``, scores and appearances (None each where absent); the
    first problem raises :class:`InputError` naming its field."""
    ann_ids, ann_image, kps, scores, apps = [], [], [], [], []
    seen: set[int] = set()
    for i, ann in enumerate(annotations):
        row = _read_annotation(ann, path, f"annotations[{i}]", index, seen)
        if row is None:
            continue  # not a person
        for column, value in zip((ann_ids, ann_image, kps, scores, apps), row):
            column.append(value)
    return ann_ids, ann_image, np.array(kps, dtype=float).reshape(len(kps), NUM_JOINTS, 3), scores, apps


def _is_int(value) -> bool:
    return type(value) is int and -(2 ** 63) <= value < 2 ** 63


def annotations_at_once(annotations: list, index: dict[int, int]) -> tuple | None:
    """What :func:`_annotations_one_by_one` returns, with every check done on all annotations
    at once (a few list passes and array operations instead of a dozen calls per
    annotation); None where any check fails, for :func:`_annotations_one_by_one` to name the
    first problem."""
    if not all(type(ann) is dict for ann in annotations):
        return None
    ids = [ann.get("id") for ann in annotations]
    image = [ann.get("image_id") for ann in annotations]
    category = [ann.get("category_id", 1) for ann in annotations]
    if not (all(map(_is_int, ids)) and all(map(_is_int, image)) and all(map(_is_int, category))
            and len(set(ids)) == len(ids) and all(i in index for i in image)):
        return None
    person = [c == 1 for c in category]
    people = annotations if all(person) else [a for a, p in zip(annotations, person) if p]
    values = [ann.get("keypoints") for ann in people]
    if not all(type(v) is list and len(v) == 3 * NUM_JOINTS for v in values):
        return None
    if people and not set(map(type, chain.from_iterable(values))) <= {float, int}:
        return None
    absent = np.array(["score" not in ann for ann in people], dtype=bool)
    scores = [ann.get("score", 0) for ann in people]
    if not set(map(type, scores)) <= {float, int}:
        return None
    try:
        kp = np.array(values, dtype=float).reshape(len(people), NUM_JOINTS, 3)
        given = np.array(scores, dtype=float)
    except OverflowError:
        return None
    if not (np.isfinite(kp).all() and (kp[..., 2] >= 0).all() and np.isfinite(given).all()
            and not (given < 0).any()):
        return None
    as_confidence(kp)                                      # as parse_keypoints
    for n in np.flatnonzero(absent):                       # as _read_annotation: the mean confidence
        present = kp[n, :, 2] > 0
        given[n] = float(kp[n, present, 2].mean()) if present.any() else 0.0
    apps = _appearances_at_once(people)
    if apps is None:
        return None
    rows = [i for i, p in enumerate(person) if p]
    return [ids[i] for i in rows], [index[image[i]] for i in rows], kp, np.minimum(given, 1.0).tolist(), apps


def _appearances_at_once(people: list) -> list | None:
    """The appearance descriptors of ``people`` (annotation dicts) as :func:`_read_annotation`
    gives them: ``[None] * N`` where none has one, ``N`` rows where all have one of the same
    length; None otherwise (a problem to name, or a mix)."""
    values = [ann.get("appearance") for ann in people]
    if all(v is None for v in values):
        return [None] * len(people)
    if not all(type(v) is list for v in values) or len(set(map(len, values))) != 1 or not values[0]:
        return None
    if not set(map(type, chain.from_iterable(values))) <= {float, int}:
        return None
    try:
        app = np.array(values, dtype=float)
    except OverflowError:
        return None
    return list(app) if np.isfinite(app).all() else None


def read_images(images: list, path: Path, allow_parent: bool = False
                 ) -> tuple[list[int], list[str], list[tuple[float, float]]]:
    """The ``images`` list -> ids, file names, (width, height); ids and names unique, names
    relative and below the file's folder (``allow_parent``: or above it through ``..``)."""
    image_ids, names, sizes, seen = [], [], [], set()
    for i, image in enumerate(images):
        field = f"images[{i}]"
        if not isinstance(image, dict):
            raise InputError(path, field, "expected an object")
        image_id = integer(image.get("id"), path, f"{field}.id")
        name = image.get("file_name")
        if not isinstance(name, str) or not name:
            raise InputError(path, f"{field}.file_name", "missing, or not a string")
        check_name(name, path, f"{field}.file_name", allow_parent)
        if image_id in seen:
            raise InputError(path, f"{field}.id", f"duplicate image id {image_id}")
        seen.add(image_id)
        image_ids.append(image_id)
        names.append(name)
        sizes.append((_size(image, "width", path, field), _size(image, "height", path, field)))
    if len(set(names)) != len(names):
        first = next(i for i, n in enumerate(names) if names.index(n) != i)
        raise InputError(path, f"images[{first}].file_name", f"duplicate file_name {names[first]!r}")
    return image_ids, names, sizes


def _read_annotation(ann, path: Path, field: str, index: dict[int, int], seen: set[int]):
    """One annotation -> ``(id, image index, keypoints (17, 3), score, appearance or None)``,
    or None when it is not a person. ``seen``: annotation ids so far (updated)."""
    ann_id, image, category = annotation_head(ann, path, field, index, seen)
    if category != 1:
        return None
    return (ann_id, image, *read_person(ann, path, field))


def annotation_head(ann, path: Path, field: str, index: dict[int, int], seen: set[int]) -> tuple[int, int, int]:
    """The annotation ``ann`` -> ``(id, image index, category)``: an object whose ``id`` is
    unique (``seen``, updated), whose ``image_id`` is one of ``index`` and whose
    ``category_id`` (default 1, a person) is an integer."""
    if not isinstance(ann, dict):
        raise InputError(path, field, "expected an object")
    ann_id = integer(ann.get("id"), path, f"{field}.id")
    if ann_id in seen:
        raise InputError(path, f"{field}.id", f"duplicate annotation id {ann_id}")
    seen.add(ann_id)
    image_id = integer(ann.get("image_id"), path, f"{field}.image_id")
    if image_id not in index:
        raise InputError(path, f"{field}.image_id", f"no image with id {image_id}")
    category = ann.get("category_id", 1)
    if isinstance(category, bool) or not isinstance(category, int):
        raise InputError(path, f"{field}.category_id", f"expected an integer, got {type(category).__name__}")
    return ann_id, index[image_id], category


def read_person(ann: dict, path: Path, field: str) -> tuple[np.ndarray, float, np.ndarray | None]:
    """A person annotation's ``keypoints (17, 3)`` (:func:`parse_keypoints`), score (default:
    the mean confidence of its present joints; clipped to 1) and appearance ``(D,)`` or None."""
    kp = parse_keypoints(ann.get("keypoints"), path, f"{field}.keypoints")
    present = kp[:, 2] > 0
    default_score = float(kp[present, 2].mean()) if present.any() else 0.0
    score = number(ann.get("score", default_score), path, f"{field}.score")
    if score < 0:
        raise InputError(path, f"{field}.score", f"negative score {score}")
    app = ann.get("appearance")
    if app is not None:
        if not isinstance(app, list) or not app:
            raise InputError(path, f"{field}.appearance", "expected a non-empty list of numbers")
        app = numbers(app, path, f"{field}.appearance")
    return kp, min(score, 1.0), app


def stack_appearance(apps: list, path: Path) -> np.ndarray | None:
    """The descriptors ``(N, D)`` (all present with one length, or all absent -> None). A
    descriptor whose norm could overflow or underflow (a largest value beyond 2**±500) is
    scaled by a power of two to a largest magnitude in [0.5, 1): exact, so its cosine
    similarities are unchanged, and 1e308 cannot make every similarity NaN."""
    with_app = [a for a in apps if a is not None]
    if not with_app:
        return None
    lengths = {len(a) for a in with_app}
    if len(with_app) != len(apps) or len(lengths) != 1:
        first_bad = next(i for i, a in enumerate(apps) if a is None or len(a) != len(with_app[0]))
        raise InputError(path, f"annotations[{first_bad}].appearance",
                         "every annotation needs an appearance descriptor of the same length, or none")
    appearance = np.array(apps, dtype=float)
    _, exponent = np.frexp(np.abs(appearance).max(axis=1))
    huge = np.abs(exponent) > 500                     # a norm that overflows or underflows
    appearance[huge] = np.ldexp(appearance[huge], -exponent[huge, None])
    return appearance


def coco_keypoints_document(file_names, sizes, ann_image, keypoints, score, ann_ids=None,
                            appearance=None) -> dict:
    """Build a COCO keypoints dataset dict. ``keypoints: (N, 17, 3)``, ``ann_image: (N,)`` index
    into ``file_names``; image ids are 1-based positions."""
    N = len(keypoints)
    ann_ids = np.arange(1, N + 1) if ann_ids is None else ann_ids
    images = [{"id": i + 1, "file_name": name, "width": int(w), "height": int(h)}
              for i, (name, (w, h)) in enumerate(zip(file_names, sizes))]
    annotations = []
    for n in range(N):
        kp = np.asarray(keypoints[n], dtype=float)
        ann = {"id": int(ann_ids[n]), "image_id": int(ann_image[n]) + 1, "category_id": 1,
               "keypoints": [round(float(v), 3) for v in kp.reshape(-1)],
               "score": round(float(score[n]), 4)}
        present = kp[:, 2] > 0
        if present.any():
            x0, y0 = kp[present, :2].min(axis=0)
            x1, y1 = kp[present, :2].max(axis=0)
            ann["bbox"] = [round(float(x0), 2), round(float(y0), 2), round(float(x1 - x0), 2), round(float(y1 - y0), 2)]
        ann["num_keypoints"] = int(present.sum())
        if appearance is not None:
            ann["appearance"] = [round(float(v), 5) for v in appearance[n]]
        annotations.append(ann)
    return {"images": images, "annotations": annotations, "categories": [COCO_PERSON_CATEGORY]}


def annotation_record(ann_id: int, image_id: int, keypoints: np.ndarray, depths: np.ndarray | None,
                      person_id: int | None = None, flags: np.ndarray | None = None) -> dict:
    """One COCO annotation with the supervision fields. ``keypoints: (17, 3)``, ``depths: (17,)``,
    ``flags: (17,)`` how each 3D joint was obtained (written as ``keypoint_flags`` names)."""
    kp = np.asarray(keypoints, dtype=float)
    vis = kp[:, 2] > 0
    x0, y0 = kp[vis, :2].min(axis=0)
    x1, y1 = kp[vis, :2].max(axis=0)
    rec = {"id": int(ann_id), "image_id": int(image_id), "category_id": 1,
           "keypoints": [round(float(v), 2) for v in kp.reshape(-1)],
           "num_keypoints": int(vis.sum()),
           "bbox": [round(float(x0), 2), round(float(y0), 2), round(float(x1 - x0), 2), round(float(y1 - y0), 2)],
           "area": round(float((x1 - x0) * (y1 - y0)), 2), "iscrowd": 0}
    if depths is not None:
        d = np.where(vis, np.asarray(depths, dtype=float), 0.0)
        rec["keypoint_depths"] = [round(float(v), 5) for v in d]
        rec["has_3d"] = [int(v) for v in (d > 0)]
    if person_id is not None:
        rec["person_id"] = int(person_id)
    if flags is not None:
        rec["keypoint_flags"] = flag_names(np.where(vis, flags, MISSING))
    return rec


def empty_dataset(description: str) -> dict:
    """A supervision data set without images yet (``info.format``: :data:`SUPERVISION_FORMAT`)."""
    return {"info": {"format": SUPERVISION_FORMAT, "description": description,
                     "keypoint_depths": "camera z of the joint / median camera z of the labelled joints of the image; "
                                        "0: missing"},
            "images": [], "annotations": [], "categories": [COCO_PERSON_CATEGORY]}
