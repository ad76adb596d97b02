"""The paper's Table 5: C_var, the consistency of a 2D detector, on reconstructed scenes.

It reads the scene directories and their reconstructions; the formula is
:func:`mvm.metrics.network.c_var`. No torch: the detector's poses are already in each scene's
``poses2d.json``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.layout import DEFAULT_OUTPUT, SceneLayout
from mvm.io.scene_dir import read_poses3d, read_scene
from mvm.metrics.network import c_var, keypoints_per_view


def evaluate_cvar(scene_dirs: list[str | Path], taus: tuple[float, ...] = (0.5, 0.9),
                  output_name: str = DEFAULT_OUTPUT) -> dict:
    """The paper's Table 5: C_var of the 2D poses of reconstructed scenes.

    For each scene, the 2D poses that the reconstruction grouped into each person
    (``<scene>/<output_name>/poses3d.json``) are triangulated pairwise per joint
    (:func:`mvm.metrics.network.c_var`); the table value is the mean over scenes, in squared
    units of each scene's model. Run it on scenes whose ``poses2d.json`` came from the
    detector under test.

    Returns:
        ``{"C_var": {tau: mean or None}, "scenes": {name: {tau: value or None}}, "missing": {…}}``.
    """
    for tau in taus:
        if not 0.0 <= tau <= 1.0:                        # NaN fails this too
            raise InputError(None, "--tau", f"expected a confidence threshold in [0, 1], got {tau}")
    per_scene, missing = {}, {}
    for scene_dir in map(Path, scene_dirs):
        poses3d = SceneLayout(scene_dir, output_name).poses3d
        if not poses3d.is_file():
            raise InputError(poses3d, None, "not found: reconstruct the scene first (mvm reconstruct)")
        scene = read_scene(scene_dir)
        persons = read_poses3d(poses3d, scene.poses)
        kp = keypoints_per_view(scene.poses.keypoints, scene.poses.view, scene.poses.score, persons.members,
                                len(scene.cameras))
        values = {}
        for tau in taus:
            v = c_var(scene.cameras.P, kp, tau)
            values[str(tau)] = float(v) if np.isfinite(v) else None
            if values[str(tau)] is None:
                missing[f"{scene_dir.name}@{tau}"] = "no joint of any person seen in three views above tau"
        per_scene[scene_dir.name] = values
    table = {}
    for tau in map(str, taus):
        vals = [v[tau] for v in per_scene.values() if v[tau] is not None]
        table[tau] = float(np.mean(vals)) if vals else None
    return {"C_var": table, "scenes": per_scene, "missing": missing}
