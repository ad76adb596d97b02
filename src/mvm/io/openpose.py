"""OpenPose JSON (``--write_json``): one file per frame, ``people[].pose_keypoints_2d``.

BODY_25 (75 numbers), COCO-18 (54 numbers) and COCO-17 (51 numbers) layouts are converted to
the 17 COCO keypoints. OpenPose marks a missing joint with ``0, 0, 0``.
"""
from __future__ import annotations

import fnmatch
import os
import re
from itertools import chain
from pathlib import Path

import numpy as np

from mvm.core.keypoints import NUM_JOINTS
from mvm.errors import InputError
from mvm.io.checks import decode_text, load_json, numbers, parse_json, read_many

#: Index of each COCO-17 keypoint in OpenPose's BODY_25 and COCO-18 layouts.
BODY25_TO_COCO17 = np.array([0, 16, 15, 18, 17, 5, 2, 6, 3, 7, 4, 12, 9, 13, 10, 14, 11])
COCO18_TO_COCO17 = np.array([0, 15, 14, 17, 16, 5, 2, 6, 3, 7, 4, 11, 8, 12, 9, 13, 10])
_LAYOUTS = {75: BODY25_TO_COCO17, 54: COCO18_TO_COCO17, 51: np.arange(NUM_JOINTS)}

_NUMBER = re.compile(r"(\d+)")


MAX_FRAME = 10 ** 9 - 1
"""The largest frame number a file name may carry (nine digits, leading zeros aside)."""


def frame_number(path: str | Path, source: str | Path | None = None, field: str | None = None) -> int:
    """The frame number in a per-frame file name: the last run of digits of the name without
    its ``_keypoints.json`` / ``.predictions.json`` / ``.json`` ending (``cam1_000012_keypoints.json``
    -> 12). Raises :class:`InputError` when there is none or it exceeds :data:`MAX_FRAME`,
    naming ``source`` and ``field`` (the file that lists the name) or else ``path``."""
    name = path.name if isinstance(path, Path) else Path(path).name
    for suffix in ("_keypoints.json", ".predictions.json", ".json"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
            break
    where = (path, None) if source is None else (source, field)
    digits = _NUMBER.findall(name)
    if not digits:
        raise InputError(*where, f"no frame number in the file name {Path(path).name!r}")
    significant = digits[-1].lstrip("0") or "0"
    if len(significant) > len(str(MAX_FRAME)):
        shown = significant if len(significant) <= 20 else significant[:12] + f"… ({len(significant)} digits)"
        raise InputError(*where, f"frame number {shown} in the file name is out of range (at most {MAX_FRAME})")
    return int(significant)


def to_coco17(values, path, field) -> np.ndarray:
    """A flat OpenPose keypoint list (75, 54 or 51 numbers) -> ``(17, 3)`` x, y, confidence."""
    flat = numbers(values, path, field, tuple(_LAYOUTS),
                   "75 (BODY_25), 54 (COCO-18) or 51 (COCO-17) numbers")
    return _coco17(flat[None])[0]


def _coco17(flat: np.ndarray) -> np.ndarray:
    """``(K, n)`` checked OpenPose keypoint lists of one layout -> ``(K, 17, 3)``, a joint of
    confidence <= 0 set to 0, 0, 0."""
    kp = flat.reshape(len(flat), -1, 3)[:, _LAYOUTS[flat.shape[1]]]                # a copy
    kp[kp[..., 2] <= 0] = 0.0
    return kp


_load_json = load_json


def read_openpose_frame(path: str | Path, root: str | Path | None = None) -> np.ndarray:
    """Read one OpenPose JSON file (inside ``root`` when given) -> ``(K, 17, 3)`` keypoints of
    its ``K`` people (pixels, confidence in [0, 1]; a missing joint is 0, 0, 0)."""
    path = Path(path)
    return openpose_people(_load_json(path, root), path)


def read_openpose_frames(paths, root: str | Path | None = None) -> list[np.ndarray]:
    """:func:`read_openpose_frame` of each of ``paths`` (files of one folder are read through
    :func:`mvm.io.checks.read_many`, which checks the folder once) -> ``[(K_i, 17, 3)]``.

    The files whose people are plain lists of numbers of one layout are converted together, a
    few array operations for all of them (per file they cost more than the parsing); any other
    file, and any bulk conversion that finds a problem, goes through :func:`openpose_people`
    file by file, so the first bad file in order is the one named."""
    paths = [p if isinstance(p, Path) else Path(p) for p in paths]
    out: list = []
    plain: list[tuple[int, Path, dict, list]] = []                      # (index in out, path, data, values)
    for path, data in zip(paths, read_many(paths, root)):
        parsed = parse_json(decode_text(data, path), path)
        values = _plain_values(parsed)
        if values is None:
            _convert_plain(plain, out)
            out.append(openpose_people(parsed, path))
        else:
            plain.append((len(out), path, parsed, values))
            out.append(None)
    _convert_plain(plain, out)
    return out


def _plain_values(data) -> list | None:
    """The ``pose_keypoints_2d`` lists of a parsed OpenPose file when every person has one, a
    list of ints and floats of one layout's length; None otherwise."""
    if not isinstance(data, dict) or type(data.get("people")) is not list:
        return None
    try:
        values = [person["pose_keypoints_2d"] for person in data["people"]]
    except (TypeError, KeyError):
        return None
    if not all(type(v) is list for v in values):
        return None
    lengths = set(map(len, values))
    if len(lengths) > 1 or not lengths <= _LAYOUTS.keys():
        return None
    return values if set(map(type, chain.from_iterable(values))) <= {float, int} else None


def _convert_plain(plain: list, out: list) -> None:
    """Fill ``out`` at the files of ``plain`` (:func:`read_openpose_frames`) with their
    ``(K, 17, 3)`` keypoints, converted in bulk per layout; then empty ``plain``."""
    layouts: dict[int, list] = {}
    for item in plain:
        layouts.setdefault(len(item[3][0]) if item[3] else 0, []).append(item)
    try:
        for n, items in layouts.items():
            if n == 0:
                for index, *_ in items:
                    out[index] = np.zeros((0, NUM_JOINTS, 3))
                continue
            flat = np.array([v for item in items for v in item[3]], dtype=float)          # (K, n)
            if not np.isfinite(flat).all():
                raise OverflowError
            people = np.split(_coco17(flat), np.cumsum([len(item[3]) for item in items])[:-1])
            for (index, *_), kp in zip(items, people):
                out[index] = kp
    except OverflowError:                            # a number too large or not finite: named file by file
        for index, path, parsed, _ in plain:
            out[index] = openpose_people(parsed, path)
    plain.clear()


def openpose_people(data, path: Path) -> np.ndarray:
    """The parsed content of the OpenPose file ``path`` -> ``(K, 17, 3)``; a problem raises
    :class:`InputError` naming the field. All people are checked and converted at once; the
    first problem is then named by the person-by-person checks."""
    if not isinstance(data, dict) or not isinstance(data.get("people"), list):
        raise InputError(path, "people", "missing, or not a list")
    people = data["people"]
    if not people:
        return np.zeros((0, NUM_JOINTS, 3))
    values = _plain_values(data)
    if values:
        try:
            flat = np.array(values, dtype=float)                                              # (K, n)
        except OverflowError:
            flat = None
        if flat is not None and np.isfinite(flat).all():
            return _coco17(flat)
    out = []
    for k, person in enumerate(people):
        if not isinstance(person, dict) or "pose_keypoints_2d" not in person:
            raise InputError(path, f"people[{k}].pose_keypoints_2d", "missing")
        out.append(to_coco17(person["pose_keypoints_2d"], path, f"people[{k}].pose_keypoints_2d"))
    return np.array(out, dtype=float).reshape(len(out), NUM_JOINTS, 3)


def frame_files(directory: str | Path, pattern: str = "*.json") -> list[tuple[int, Path]]:
    """Per-frame files of ``directory`` as ``[(frame number, path)]`` sorted by frame *number*
    (never by string). Two files with the same number raise :class:`InputError`."""
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(directory, None, "not a directory")
    with os.scandir(directory) as entries:
        paths = [directory / e.name for e in entries if fnmatch.fnmatchcase(e.name, pattern) and e.is_file()]
    files = sorted(((frame_number(p), p) for p in paths), key=lambda item: item[0])
    numbers = [n for n, _ in files]
    for a, b in zip(numbers, numbers[1:]):
        if a == b:
            raise InputError(directory, None, f"two files for frame {a}")
    return files


def read_openpose_dir(directory: str | Path) -> dict[int, np.ndarray]:
    """Read every OpenPose JSON file of ``directory``: ``{frame number: (K, 17, 3)}``."""
    return {n: read_openpose_frame(p) for n, p in frame_files(directory, "*.json")}
