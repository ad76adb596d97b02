"""Detections made elsewhere -> the 2D poses of a scene's frames (``mvm detect --import``).

The formats (:data:`mvm.io.pose_format.POSE_FORMATS`, told by :func:`mvm.io.pose_format.pose_format`):

- ``openpifpaf``: a folder of OpenPifPaf ``--json-output`` files, one per image;
- ``openpose``: a folder of OpenPose JSON files (BODY_25, COCO-18), one per frame;
- ``coco-results``: a COCO results file, ``image_id`` a frame's file name or its 1-based
  position in the scene's frame list (:func:`mvm.io.coco_results.results_frame_index`);
- ``coco``: a COCO keypoints data set, images matched to frames by ``file_name``.

Per-frame files are matched to frames by the frame number in their names (the numbers of
``frames.json`` when the scene has one). Detections of frames the scene lacks are reported
and left out. The readers are :mod:`mvm.io`'s; this module only places their poses.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from mvm.core.keypoints import NUM_JOINTS
from mvm.errors import InputError
from mvm.io.coco import as_confidence, read_coco_keypoints
from mvm.io.coco_results import read_coco_results, results_frame_index
from mvm.io.layout import FRAMES_INDEX
from mvm.io.openpifpaf import read_openpifpaf_dir
from mvm.io.openpose import frame_number, read_openpose_dir
from mvm.io.pose_format import POSE_FORMATS, pose_format
from mvm.video.frames import read_frame_index

log = logging.getLogger(__name__)


def import_detections(source: str | Path, scene: str | Path, names: list[str],
                      fmt: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read detections of the frames ``names`` of ``scene`` from ``source`` in format ``fmt``
    (told by :func:`mvm.io.pose_format.pose_format` when None) -> ``keypoints (N, 17, 3)``,
    ``image (N,)`` index into ``names``, ``score (N,)``."""
    source, scene = Path(source), Path(scene)
    fmt = fmt or pose_format(source)[0]
    if fmt not in POSE_FORMATS:
        raise InputError(source, None, f"unknown format {fmt!r} (known: {', '.join(POSE_FORMATS)})")
    if fmt == "coco-results":
        return coco_results_in_scene(source, names)
    if fmt == "coco":
        return _coco_in_scene(source, names)
    numbers = _frame_numbers(scene, names)
    if fmt == "openpifpaf":
        return _from_per_frame(read_openpifpaf_dir(source), numbers, source)
    return _from_per_frame(read_openpose_dir(source), numbers, source)


#: Imported keypoints outside the frame (by more than 5% of its size) above this fraction of
#: the confident ones: the detections were made on frames of another size.
OUTSIDE_LIMIT = 0.05


def check_detections_fit(keypoints: np.ndarray, size: tuple[int, int], source: str | Path) -> None:
    """Refuse, in one :class:`InputError` line naming ``source``, detections made on frames of
    another size: more than :data:`OUTSIDE_LIMIT` of the confident keypoints of ``keypoints:
    (N, 17, 3)`` lie outside the ``size`` (w, h) frames (by over 5% of their size)."""
    w, h = size
    xy = keypoints[keypoints[..., 2] > 0][:, :2]
    if not len(xy) or w <= 0 or h <= 0:
        return
    outside = (xy[:, 0] < -0.05 * w) | (xy[:, 0] > 1.05 * w) | (xy[:, 1] < -0.05 * h) | (xy[:, 1] > 1.05 * h)
    if outside.mean() > OUTSIDE_LIMIT:
        x, y = np.nanmax(xy, axis=0)
        raise InputError(source, None, f"{outside.mean():.0%} of the keypoints lie outside the {w}×{h} frames "
                                       f"(they reach x = {x:.0f}, y = {y:.0f} px): detections made on frames of "
                                       "another size? Extract the frames at that size (--width), or scale them")


def imported_keypoints(source: str | Path, fmt: str | None = None) -> np.ndarray:
    """Every pose of ``source`` whatever its frame -> ``keypoints: (N, 17, 3)``, confidence in
    [0, 1]: for the checks made before any work (:func:`check_detections_fit`)."""
    source = Path(source)
    fmt = fmt or pose_format(source)[0]
    if fmt == "coco-results":
        return as_confidence(read_coco_results(source).keypoints)
    if fmt == "coco":
        return read_coco_keypoints(source).keypoints
    per_frame = read_openpifpaf_dir(source) if fmt == "openpifpaf" else read_openpose_dir(source)
    kps = [v[0] if isinstance(v, tuple) else v for v in per_frame.values()]
    return np.concatenate(kps) if kps else np.zeros((0, NUM_JOINTS, 3))


def coco_results_in_scene(path: str | Path, names: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The COCO results file ``path`` -> ``keypoints: (N, 17, 3)`` (confidence in [0, 1]),
    ``image: (N,)`` index into ``names``, ``score: (N,)`` (in [0, 1]; where the file gives none,
    the mean confidence of the present joints). ``image_id`` is a frame's file name (or its
    stem), or its 1-based position in ``names``."""
    path = Path(path)
    results = read_coco_results(path)
    image = results_frame_index(results, names)
    if names and any(not isinstance(i, str) for i in results.image_ids):
        log.info("%s: an integer image_id is a 1-based position in the scene's frame list (1 = %s)", path, names[0])
    keep = image >= 0
    if not keep.all():
        log.warning("%s: %d results name images that are not in the scene and are ignored", path, int((~keep).sum()))
    keypoints = as_confidence(results.keypoints[keep])
    score = results.score[keep]
    for n in np.flatnonzero(np.isnan(score)):
        present = keypoints[n, :, 2] > 0
        score[n] = float(keypoints[n, present, 2].mean()) if present.any() else 0.0
    return keypoints, image[keep], np.minimum(score, 1.0)


def _coco_in_scene(path: Path, names: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A COCO keypoints data set's poses on the frames ``names`` (by ``file_name``)."""
    coco = read_coco_keypoints(path)
    by_name = {n: i for i, n in enumerate(names)}
    index = np.array([by_name.get(coco.file_names[i], -1) for i in coco.ann_image], dtype=np.int64)
    if (index < 0).any():
        log.warning("%s: %d poses are in images not in the scene and are ignored", path, int((index < 0).sum()))
    keep = index >= 0
    return coco.keypoints[keep], index[keep], coco.score[keep]


def _frame_numbers(scene: Path, names: list[str]) -> dict[int, int]:
    """Frame number -> index into ``names`` (numbers from frames.json, else from the names)."""
    if (scene / FRAMES_INDEX).is_file():
        index = read_frame_index(scene)
        number_of = dict(zip(index.names, index.numbers.tolist()))
        return {int(number_of[n]): i for i, n in enumerate(names) if n in number_of}
    return {frame_number(n): i for i, n in enumerate(names)}


def _from_per_frame(per_frame: dict, numbers: dict[int, int], source: Path):
    """``{frame number: keypoints (K, 17, 3) or (keypoints, scores (K,))}`` -> ``keypoints
    (N, 17, 3)``, ``image (N,)``, ``score (N,)`` (without scores: the mean confidence of the
    present joints) of the frames in ``numbers``."""
    keypoints, image, score = [], [], []
    unknown = sorted(set(per_frame) - set(numbers))
    if unknown:
        log.warning("%s: detections for %d frames not in the scene are ignored (e.g. frame %d)",
                    source, len(unknown), unknown[0])
    for number, value in per_frame.items():
        if number not in numbers:
            continue
        kp, sc = value if isinstance(value, tuple) else (value, None)
        if sc is None:
            present = kp[:, :, 2] > 0
            sc = np.where(present, kp[:, :, 2], 0).sum(1) / np.maximum(present.sum(1), 1)
        keypoints.append(kp)
        score.append(sc)
        image.append(np.full(len(kp), numbers[number]))
    return (np.concatenate(keypoints) if keypoints else np.zeros((0, NUM_JOINTS, 3)),
            np.concatenate(image).astype(np.int64) if image else np.zeros(0, np.int64),
            np.concatenate(score) if score else np.zeros(0))
