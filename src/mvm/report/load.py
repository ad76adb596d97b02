"""Read what a report needs from a scene directory: the scene, its reconstruction
(``<output>/poses3d.json``), the ground truth of a simulated scene and the frames."""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.core.scene import Persons3D, Scene
from mvm.errors import InputError
from mvm.io.checks import load_json_object
from mvm.io.ground_truth import GroundTruth
from mvm.io.layout import DEFAULT_OUTPUT, FRAMES, POSES3D, TIMINGS, SceneLayout
from mvm.io.scene_dir import (
    check_reconstruction_fresh,
    load_poses3d_document,
    output_dir,
    parse_poses3d,
    read_scene,
)

log = logging.getLogger(__name__)


@dataclass
class SceneResult:
    """A scene with its reconstruction.

    Attributes:
        path: the scene directory; output: its output folder name (``mvm``).
        scene, persons: as read (``persons.members`` index ``scene.poses``).
        metrics, timings: ``metrics`` of ``poses3d.json`` and the seconds of ``timings.json`` (may be empty).
        truth: the ground truth of a simulated scene, or None.
        true_person: ``(N,)`` the true person of every 2D pose (-1: false), or None.
    """

    path: Path
    output: str
    scene: Scene
    persons: Persons3D
    metrics: dict
    timings: dict
    truth: GroundTruth | None = None
    true_person: np.ndarray | None = None

    @property
    def out_dir(self) -> Path:
        return output_dir(self.path, self.output)

    @property
    def frames_dir(self) -> Path | None:
        frames = self.path / FRAMES
        return frames if frames.is_dir() else None


def read_truth(path: Path, annotation_ids: np.ndarray) -> tuple[GroundTruth, np.ndarray]:
    """Read ``<scene>.groundtruth.json``: the truth and the true person ``(N,)`` of the
    annotations ``annotation_ids: (N,)`` (the truth lists annotations by id 1, 2, …)."""
    try:
        truth = GroundTruth.from_json(load_json_object(path, what="a ground truth object"))
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(path, None, f"not a ground truth document: {e}") from None
    if truth.poses3d.ndim != 3 or truth.poses3d.shape[1:] != (17, 3):
        raise InputError(path, "poses3d", f"expected shape (G, 17, 3), got {truth.poses3d.shape}")
    ids = np.asarray(annotation_ids, dtype=np.int64)
    if len(ids) and (ids.min() < 1 or ids.max() > len(truth.person)):
        raise InputError(path, "person_of_annotation",
                         f"has {len(truth.person)} entries, annotation ids go up to {ids.max()}")
    return truth, truth.person[ids - 1].astype(np.int64)


def _object(document: dict, key: str, path: Path) -> dict:
    """``document[key]``: an object, or empty when absent or null; anything else is an InputError."""
    value = document.get(key)
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise InputError(path, key, f"expected an object, got {type(value).__name__}")
    return value


def _timings(document: dict, poses3d: Path, scene_dir: Path) -> dict:
    """The seconds of the reconstruction's steps: ``timings.json`` beside ``poses3d.json``, or
    the ``timings_s`` of a ``poses3d.json`` an earlier version wrote."""
    path = poses3d.parent / TIMINGS
    if path.is_file():
        return load_json_object(path, root=scene_dir, what="an object of seconds")
    return _object(document, "timings_s", poses3d)


def _seconds(value) -> float | None:
    """A duration of ``timings_s`` as a finite float, or None for anything else (not shown)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        value = float(value)
    except OverflowError:
        return None
    return value if math.isfinite(value) else None


def load_result(scene_dir: str | Path, output: str = DEFAULT_OUTPUT) -> SceneResult:
    """Read a reconstructed scene directory (and its ground truth when one lies beside it). A
    ``poses3d.json`` whose inputs changed since it was made is refused in one line naming the
    command to run (:func:`mvm.io.scene_dir.check_reconstruction_fresh`)."""
    path = Path(scene_dir)
    scene = read_scene(path)
    poses3d = output_dir(path, output) / POSES3D
    if not (poses3d.exists() or poses3d.is_symlink()):
        raise InputError(poses3d, None, "missing: reconstruct the scene first (mvm reconstruct)")
    check_reconstruction_fresh(path, poses3d)
    document = load_poses3d_document(poses3d, root=path)
    persons = parse_poses3d(document, poses3d, scene.poses)
    metrics = _object(document, "metrics", poses3d)
    timings = {k: t for k, t in ((k, _seconds(v)) for k, v in _timings(document, poses3d, path).items())
               if t is not None}
    truth = true_person = None
    gt = SceneLayout(path).truth
    if gt.is_file():
        truth, true_person = read_truth(gt, scene.poses.ids)
        log.info("%s: ground truth of %d persons", gt, len(truth.poses3d))
    return SceneResult(path, output, scene, persons, dict(metrics), dict(timings), truth, true_person)
