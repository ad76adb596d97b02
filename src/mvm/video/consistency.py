"""How consistent a 2D detector is across the frames of a reconstructed scene: the paper's
C_var (Table 5, :func:`mvm.eval.network.c_var`), so that detectors can be compared on one's
own clips: detect with each, reconstruct, and compare C_var (lower: more consistent).

The persons of ``poses3d.json`` say which 2D poses show the same person (their ``members``);
each person's joints seen with confidence ≥ τ in at least three frames are triangulated pair
by pair, and C_var is the mean variance of those pairwise points (squared world units: m²
once the scene has a metric scale).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mvm.core.keypoints import NUM_JOINTS
from mvm.core.scene import Persons3D, Poses2D
from mvm.eval.network import c_var


def keypoints_by_view(persons: Persons3D, poses: Poses2D, views: int) -> np.ndarray:
    """Each person's 2D keypoints in each view: ``(P, V, 17, 3)`` (0 where the person has no
    pose in a view; of two poses in one view, the higher-scoring one)."""
    out = np.zeros((len(persons), views, NUM_JOINTS, 3))
    for p, members in enumerate(persons.members):
        members = np.asarray(members, dtype=np.int64)
        best = members[np.argsort(-poses.score[members], kind="stable")]
        view, first = np.unique(poses.view[best], return_index=True)
        out[p, view] = poses.keypoints[best[first]]
    return out


def scene_c_var(scene: str | Path, output: str = "mvm", taus: tuple[float, ...] = (0.5, 0.9)) -> dict:
    """C_var of the 2D poses of a reconstructed ``scene`` at each threshold τ in ``taus``.

    Returns ``{"c_var": {τ: value}, "persons": P, "views": V, "detector": what produced
    poses2d.json (its ``info.source``, or None)}``; a value is NaN when no joint has three
    views above τ.
    """
    import json

    from mvm.io.scene_dir import read_poses3d, read_scene

    scene = Path(scene)
    s = read_scene(scene)
    persons = read_poses3d(scene / output / "poses3d.json", s.poses)
    kp = keypoints_by_view(persons, s.poses, len(s.cameras))
    P = s.cameras.P
    try:
        info = json.loads((scene / "poses2d.json").read_text()).get("info", {})
    except (OSError, ValueError, AttributeError):
        info = {}
    return {"c_var": {float(t): c_var(P, kp, t) for t in taus}, "persons": len(persons), "views": len(s.cameras),
            "detector": info.get("source") if isinstance(info, dict) else None}
