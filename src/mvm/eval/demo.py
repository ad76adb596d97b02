"""The built-in default: simulate a mannequin scene, reconstruct it, compare with the truth."""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from mvm.core.config import Config
from mvm.io.ground_truth import write_simulation
from mvm.io.layout import SceneLayout
from mvm.metrics.poses import MATCH_DISTANCE_M, match_persons, matching_precision_recall, pose_errors
from mvm.scenes import reconstruct_dir
from mvm.sim.simulate import SimConfig, simulate


def evaluate(result, truth) -> dict:
    """Ground-truth metrics of a reconstruction of a simulated scene (lengths in mm)."""
    poses = result.scene.poses
    person_of_id = dict(zip(range(1, len(truth.person) + 1), truth.person))
    true_person = np.array([person_of_id[int(i)] for i in poses.ids])
    precision, recall = matching_precision_recall(result.persons.members, true_person)
    pairs = match_persons(result.persons.keypoints3d, truth.poses3d, MATCH_DISTANCE_M)
    errors = pose_errors(result.persons.keypoints3d, truth.poses3d, pairs)
    return {
        "persons_found": len(pairs),
        "persons_estimated": len(result.persons),
        "persons_true": len(truth.poses3d),
        "poses": len(poses),
        "false_poses": int((true_person < 0).sum()),
        "precision": precision,
        "recall": recall,
        "mpjpe_mm": 1000 * errors["mpjpe"],
        "pa_mpjpe_mm": 1000 * errors["pa_mpjpe"],
        **{k: result.metrics[k] for k in ("E_R_px", "outliers", "G_k")},
        "timings": result.timings,
    }


def run_demo(out_dir: Path, sim: SimConfig | None = None, config: Config | None = None,
             render: bool = False, progress: Callable[[str, int, int | None], None] | None = None) -> dict:
    """Simulate into ``out_dir/scene`` (ground truth beside it), reconstruct, evaluate. With
    ``render`` the frames are rendered into ``out_dir/scene/frames`` too (for report, overlay,
    export and training). ``progress(stage, done, total)``: ``rendering`` frame by frame,
    ``reconstructing`` at its start and end."""
    tell = progress or (lambda stage, done, total: None)
    sim = sim or SimConfig()
    scene, truth = simulate(sim)
    scene_dir = Path(out_dir) / "scene"
    truth_path = write_simulation(scene_dir, scene, truth, sim)
    if render:
        from mvm.sim.mannequin_video import render_frames

        render_frames(SceneLayout(scene_dir).frames, scene.cameras, truth.poses3d, sim.seed,
                      progress=lambda done, total: tell("rendering", done, total))
    tell("reconstructing", 0, 1)
    result = reconstruct_dir(scene_dir, config or Config())
    tell("reconstructing", 1, 1)
    report = evaluate(result, truth)
    report.update(scene=str(scene_dir), poses3d=str(SceneLayout(scene_dir).poses3d),
                  ground_truth=str(truth_path))
    return report
