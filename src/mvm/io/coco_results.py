"""COCO keypoint *results* files: a JSON list of detections
``{"image_id", "category_id", "keypoints": [51 numbers], "score"}`` (what pycocotools'
``loadRes`` and the COCO keypoint challenge take).

The file is read the guarded way (:func:`mvm.io.checks.read_bytes`) and every problem is one
:class:`~mvm.errors.InputError` line naming the file and the entry (``[k].score``): an entry
that is not an object, a ``category_id`` that is not an integer, an ``image_id`` that is
neither a file name nor an integer, keypoints that are not 51 finite numbers or have a
negative confidence, a score that is not a finite number (``"high"``, a 400-digit number) or
is negative. Entries of another category than 1 (person) are left out.

``image_id`` is matched according to what the detections are of:

- :func:`results_image_index`, detections of a COCO data set (evaluation): an integer is an
  image ``id`` of the set, a string a ``file_name`` (or its stem); an id the set lacks is an
  error naming the file, the entry and the id;
- :func:`results_frame_index`, detections of a scene's frames (``mvm detect --import``): a
  string is a frame's file name (or its stem); an **integer is the frame's 1-based position
  in the scene's frame list** (the frames in the order of ``frames.json``, else the images
  of ``frames/`` sorted by the number in their names), not a COCO image id; a result whose frame
  is not in the scene is left out.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.core.keypoints import NUM_JOINTS
from mvm.errors import InputError
from mvm.io.checks import integer, load_json, number, numbers


@dataclass(frozen=True)
class CocoResults:
    """The person detections of a COCO results file.

    Attributes:
        image_ids: ``N`` image ids as the file gives them (int or str).
        entries: ``(N,)`` each detection's position in the file (for messages: ``[k]``).
        keypoints: ``(N, 17, 3)`` x, y, confidence exactly as the file gives them (finite,
            confidence >= 0; a joint of confidence 0 keeps its coordinates).
        score: ``(N,)`` the scores as given (finite, >= 0); NaN where the file gives none.
    """

    image_ids: tuple
    entries: np.ndarray
    keypoints: np.ndarray
    score: np.ndarray


def read_coco_results(path: str | Path, root: str | Path | None = None, require_score: bool = False) -> CocoResults:
    """Read and validate the COCO results file ``path`` (inside ``root`` when given); with
    ``require_score``, every detection must have a ``score``."""
    path = Path(path)
    data = load_json(path, root)
    if not isinstance(data, list):
        raise InputError(path, None, "expected a JSON list of results")
    image_ids, entries, keypoints, scores = [], [], [], []
    for k, item in enumerate(data):
        field = f"[{k}]"
        if not isinstance(item, dict):
            raise InputError(path, field, "expected an object")
        category = item.get("category_id", 1)
        if isinstance(category, bool) or not isinstance(category, int):
            raise InputError(path, f"{field}.category_id", f"expected an integer, got {type(category).__name__}")
        if category != 1:
            continue
        image_ids.append(_image_id(item.get("image_id"), path, f"{field}.image_id"))
        kp = numbers(item.get("keypoints"), path, f"{field}.keypoints", (3 * NUM_JOINTS,),
                     f"{3 * NUM_JOINTS} numbers (17 keypoints × x, y, v)").reshape(NUM_JOINTS, 3)
        if (kp[:, 2] < 0).any():
            raise InputError(path, f"{field}.keypoints", "negative keypoint confidence")
        if "score" in item:
            score = number(item["score"], path, f"{field}.score")
            if score < 0:
                raise InputError(path, f"{field}.score", f"negative score {score}")
        elif require_score:
            raise InputError(path, f"{field}.score", "missing")
        else:
            score = np.nan
        entries.append(k)
        keypoints.append(kp)
        scores.append(score)
    N = len(keypoints)
    return CocoResults(tuple(image_ids), np.array(entries, dtype=np.int64),
                       np.array(keypoints, dtype=float).reshape(N, NUM_JOINTS, 3), np.array(scores, dtype=float))


def _image_id(value, path: Path, field: str) -> int | str:
    if isinstance(value, str) and value:
        return value
    if isinstance(value, int) and not isinstance(value, bool):
        return integer(value, path, field)
    shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:39] + "…"
    raise InputError(path, field, f"expected a file name or an integer, got {shown}")


def _by_name(names) -> dict[str, int]:
    """Each file name, and each file name's stem, -> its index."""
    index = {n: i for i, n in enumerate(names)}
    index.update({Path(n).stem: i for i, n in enumerate(names)})
    return index


def _name_index(image_id: str, by_name: dict[str, int]) -> int:
    found = by_name.get(image_id)
    return by_name.get(Path(image_id).stem, -1) if found is None else found


def results_frame_index(results: CocoResults, names) -> np.ndarray:
    """``(N,)`` the frame of each detection as an index into the scene's frame list ``names``,
    -1 where the frame is not in the scene: a string ``image_id`` is a frame's file name (or
    its stem, or a name whose stem is one), an integer its 1-based position in ``names``."""
    names = list(names)
    by_name = _by_name(names)
    out = np.full(len(results.image_ids), -1, dtype=np.int64)
    for n, image_id in enumerate(results.image_ids):
        if isinstance(image_id, str):
            out[n] = _name_index(image_id, by_name)
        elif 1 <= image_id <= len(names):
            out[n] = image_id - 1
    return out


def results_image_index(results: CocoResults, path: str | Path, image_ids, file_names) -> np.ndarray:
    """``(N,)`` the image of each detection as an index into a data set's images (``image_ids``
    and ``file_names``, ``I`` each): an integer ``image_id`` is an image id, a string a file
    name (or its stem). An image the data set lacks raises :class:`InputError` naming
    ``path``, the entry and the id."""
    by_id = {int(i): k for k, i in enumerate(image_ids)}
    by_name = _by_name(file_names)
    out = np.empty(len(results.image_ids), dtype=np.int64)
    for n, image_id in enumerate(results.image_ids):
        found = _name_index(image_id, by_name) if isinstance(image_id, str) else by_id.get(image_id, -1)
        if found < 0:
            raise InputError(path, f"[{results.entries[n]}].image_id",
                             f"no image with id {image_id!r} in the ground truth")
        out[n] = found
    return out
