"""C_var of a detector on a reconstructed scene: grouping each person's 2D poses by view, and
the variance growing with the detector's noise (known cameras, known people)."""
from __future__ import annotations

import numpy as np
import pytest

from mvm.core.scene import Persons3D, Poses2D
from mvm.io.scene_dir import poses3d_document, write_poses3d, write_scene
from mvm.sim.projection import project_people
from mvm.video.consistency import keypoints_by_view, scene_c_var

from helpers import random_cameras, standing_poses

V, P = 8, 2


def _detections(noise_px: float, seed: int = 0):
    """Two people seen in every view with Gaussian pixel noise; the persons that group them."""
    rng = np.random.default_rng(seed)
    cameras = random_cameras(rng, V)
    people = standing_poses(P, seed) + np.array([[[-0.5, 0, 0]], [[0.5, 0, 0]]])
    uv, _ = project_people(cameras, people)                                  # (V, P, 17, 2)
    kp = np.concatenate([uv + rng.normal(0, noise_px, uv.shape), np.ones(uv.shape[:3] + (1,))], -1)
    kp[:, 1, 3, 2] = 0.6                                                    # one joint below τ = 0.9
    poses = Poses2D(kp.reshape(-1, 17, 3), np.repeat(np.arange(V), P), np.arange(V * P) + 100,
                    np.full(V * P, 0.9))
    members = [np.arange(p, V * P, P) for p in range(P)]
    persons = Persons3D(people, np.ones((P, 17)), members, np.full((P, 17), V), np.zeros((P, 17)), np.zeros(P))
    return cameras, poses, persons, people


def test_keypoints_by_view_takes_each_persons_best_pose_per_view():
    _, poses, persons, _ = _detections(0.0)
    kp = keypoints_by_view(persons, poses, V)
    assert kp.shape == (P, V, 17, 3)
    assert np.allclose(kp[1, 3], poses.keypoints[3 * P + 1])
    # a weaker duplicate in view 0 does not replace the better pose
    extra = Poses2D(np.concatenate([poses.keypoints, poses.keypoints[:1] + 50]), np.append(poses.view, 0),
                    np.append(poses.ids, 999), np.append(poses.score, 0.1))
    persons.members[0] = np.append(persons.members[0], V * P)
    assert np.allclose(keypoints_by_view(persons, extra, V)[0, 0], poses.keypoints[0])


def test_scene_c_var_grows_with_detector_noise(tmp_path):
    values = []
    for noise in (0.0, 2.0, 8.0):
        cameras, poses, persons, _ = _detections(noise)
        scene = tmp_path / f"noise{noise}"
        write_scene(scene, cameras, poses)
        (scene / "mvm").mkdir()
        write_poses3d(scene / "mvm" / "poses3d.json", poses3d_document(persons, poses, {}))
        result = scene_c_var(scene, taus=(0.5, 0.9))
        assert result["persons"] == P and result["views"] == V
        values.append(result["c_var"][0.5])
        assert np.isfinite(result["c_var"][0.9])
    assert values[0] < 1e-8
    assert 0 < values[1] < values[2]
    # variance scales with the square of the pixel noise (same noise pattern, 4× the size)
    assert values[2] / values[1] == pytest.approx(16, rel=0.5)
