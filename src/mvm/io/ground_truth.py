"""The ground truth of a simulated scene and its file, ``<scene>.groundtruth.json``, written
beside the scene directory (outside it, so the scene stays a plain input).

Format ``mvm.groundtruth/1``: ``poses3d`` ``(G, 17, 3)`` metres, ``person_of_annotation``
``(N,)`` the true person of the annotation with id ``i + 1`` (-1: a false pose), ``labels``
the postures, optionally ``merged_with`` ``(N,)`` and ``simulation`` (the settings).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from mvm.core.keypoints import NUM_JOINTS
from mvm.errors import InputError
from mvm.io.layout import SceneLayout

FORMAT = "mvm.groundtruth/1"


@dataclass
class GroundTruth:
    """The truth of a simulated scene.

    Attributes:
        poses3d: ``(G, 17, 3)`` world joints (metres).
        person: ``(N,)`` true person of every 2D pose (-1: a false positive); for a pose that
            merges two people, the person its upper body comes from.
        labels: ``G`` postures ('standing', 'sitting', 'crouching', 'other'; empty if unknown).
        merged_with: ``(N,)`` the second person of a merged pose, -1 otherwise (None: unknown).
    """

    poses3d: np.ndarray
    person: np.ndarray
    labels: tuple[str, ...] = ()
    merged_with: np.ndarray | None = field(default=None)

    def to_json(self) -> dict:
        document = {"format": FORMAT, "poses3d": np.round(self.poses3d, 6).tolist(),
                    "person_of_annotation": self.person.tolist(), "labels": list(self.labels)}
        if self.merged_with is not None:
            document["merged_with"] = self.merged_with.tolist()
        return document

    @classmethod
    def from_json(cls, data: dict) -> GroundTruth:
        merged = data.get("merged_with")
        return cls(np.array(data["poses3d"], dtype=float), np.array(data["person_of_annotation"]),
                   tuple(data.get("labels", ())), None if merged is None else np.array(merged))


def write_simulation(path: str | Path, scene, truth: GroundTruth, config=None) -> Path:
    """Write the scene directory ``path`` and the ground truth beside it
    (:attr:`mvm.io.layout.SceneLayout.truth`), with the simulation's settings (a dataclass) when given.
    Returns the truth's path."""
    from mvm.io.files import atomic_write_json
    from mvm.io.outputs import check_names, writing_into
    from mvm.io.scene_dir import write_scene

    path = Path(path)
    truth_path = SceneLayout(path).truth
    check_names(truth_path.parent, [truth_path.name])     # a user's file of that name: refused before any write
    document = truth.to_json()
    if config is not None:
        document["simulation"] = asdict(config)
    write_scene(path, scene.cameras, scene.poses)
    with writing_into(truth_path.parent, [truth_path.name]):
        atomic_write_json(truth_path, document)
    return truth_path


def read_ground_truth(path: str | Path) -> GroundTruth:
    """Read ``<scene>.groundtruth.json`` as written by :func:`write_simulation`."""
    from mvm.io.checks import load_json

    path = Path(path)
    data = load_json(path)
    if not isinstance(data, dict):
        raise InputError(path, None, f"expected a JSON object, got {type(data).__name__}")
    for key in ("poses3d", "person_of_annotation"):
        if key not in data:
            raise InputError(path, key, "missing")
    try:
        truth = GroundTruth.from_json(data)
    except (TypeError, ValueError) as e:
        raise InputError(path, None, f"not a ground truth document: {e}") from None
    if truth.poses3d.ndim != 3 or truth.poses3d.shape[1:] != (NUM_JOINTS, 3):
        raise InputError(path, "poses3d", f"expected (G, 17, 3), got {truth.poses3d.shape}")
    if truth.person.ndim != 1 or (truth.person.size and truth.person.dtype.kind not in "iu"):
        raise InputError(path, "person_of_annotation", "expected a list of integers")
    truth.person = truth.person.astype(int)
    return truth
