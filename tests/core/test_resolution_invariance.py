"""The reconstruction measures image distances in person sizes (:mod:`mvm.core.image_units`):
the same scene with its image coordinates and intrinsics scaled by 0.5, 2 or 4 gives the same
persons and the same 3D poses, for a scene of one moving camera and for the instants of a rig."""
from __future__ import annotations

import numpy as np
import pytest

from mvm.core.config import Config
from mvm.core.reconstruct import reconstruct
from mvm.core.refine_units import MAX_SPREAD_FACTOR
from mvm.core.scene import Cameras, Poses2D, Scene
from mvm.rig.instants import reconstruct_instants, rig_poses
from mvm.sim.detector import DetectorErrors, pose_scores
from mvm.sim.rig import detect_views, ring_cameras, walking_people
from mvm.sim.simulate import SimConfig, simulate

FACTORS = (0.5, 2.0, 4.0)


def scaled_cameras(cameras: Cameras, factor: float) -> Cameras:
    """The cameras with their images scaled by ``factor``: ``diag(f, f, 1) K`` and the sizes."""
    K = cameras.K * np.array([factor, factor, 1.0])[:, None]
    return Cameras(K, cameras.R, cameras.t, cameras.size * factor, cameras.names)


def scaled_poses(poses: Poses2D, factor: float) -> Poses2D:
    keypoints = poses.keypoints.copy()
    keypoints[..., :2] *= factor
    return Poses2D(keypoints, poses.view, poses.ids, poses.score, poses.appearance, poses.instant)


@pytest.fixture(scope="module")
def scene() -> Scene:
    scene, _ = simulate(SimConfig.preset("hard", people=4, frames=24, seed=3))
    return scene


@pytest.mark.parametrize("factor", FACTORS)
def test_a_scene_scaled_gives_the_same_persons_and_poses(scene, factor):
    config = Config()
    base = reconstruct(scene, config)
    scaled = reconstruct(Scene(scene.name, scaled_cameras(scene.cameras, factor), scaled_poses(scene.poses, factor),
                               scene.points3d), config)
    assert len(base.persons) >= 3
    assert [m.tolist() for m in scaled.persons.members] == [m.tolist() for m in base.persons.members]
    np.testing.assert_array_equal(np.isnan(scaled.persons.keypoints3d), np.isnan(base.persons.keypoints3d))
    np.testing.assert_allclose(scaled.persons.keypoints3d, base.persons.keypoints3d, atol=1e-6, equal_nan=True)
    np.testing.assert_array_equal(scaled.persons.views_per_joint, base.persons.views_per_joint)
    # What the settings came to in pixels scales with the images.
    assert scaled.metrics["ransac_threshold_px"] == pytest.approx(factor * base.metrics["ransac_threshold_px"])
    assert scaled.metrics["E_R_px"] == pytest.approx(factor * base.metrics["E_R_px"], rel=1e-6)


@pytest.fixture(scope="module")
def rig():
    rng = np.random.default_rng(7)
    cameras = ring_cameras(6)
    people = walking_people(3, 6, rng)
    errors = DetectorErrors(noise=0.02, dropout=0.05, swap_prob=0.05, outlier_joint_prob=0.04, false_pose_rate=0.5)
    kps, cams, inst = [], [], []
    for t, X in enumerate(people):
        k, c, _ = detect_views(cameras, X, rng, errors)
        kps.append(k)
        cams.append(c)
        inst.append(np.full(len(c), t))
    keypoints = np.concatenate(kps)
    return cameras, rig_poses(keypoints, np.concatenate(inst), np.concatenate(cams), pose_scores(keypoints))


@pytest.mark.parametrize("factor", FACTORS)
def test_a_rig_scaled_gives_the_same_persons_and_poses(rig, factor):
    cameras, poses = rig
    config = Config()
    base = reconstruct_instants(cameras, poses, config, workers=1)
    scaled = reconstruct_instants(scaled_cameras(cameras, factor), scaled_poses(poses, factor), config, workers=1)
    assert len(base) >= 15
    np.testing.assert_array_equal(scaled.instant, base.instant)
    np.testing.assert_array_equal(scaled.members, base.members)
    np.testing.assert_array_equal(scaled.inliers, base.inliers)
    np.testing.assert_allclose(scaled.X, base.X, atol=1e-6, equal_nan=True)


def test_a_pixel_threshold_would_not_be_invariant(scene):
    """The property is not vacuous: the same scene at a quarter of the resolution with the
    RANSAC threshold held in pixels (scaled by 4 in person sizes) changes the inliers."""
    config = Config()
    base = reconstruct(scene, config)
    small = Scene(scene.name, scaled_cameras(scene.cameras, 0.25), scaled_poses(scene.poses, 0.25), scene.points3d)
    held = reconstruct(small, config.replace(ransac_threshold=4 * config.ransac_threshold))
    assert held.persons.views_per_joint.sum() != base.persons.views_per_joint.sum()


def test_the_refinement_follows_the_noise_the_scene_measures():
    """A detector twice as noisy (in person sizes) gives a RANSAC threshold, a robust scale and a
    prior weight that grow with the measured noise (the weight as its square), and the recorded
    values are those the settings imply (the weight times the narrow arc's spread factor, the
    same for both: the same tour)."""
    config = Config()
    spread = []
    metrics = {}
    for noise in (0.01, 0.02):
        scene, _ = simulate(SimConfig.preset("realistic", people=3, frames=16, seed=5, noise=noise))
        metrics[noise] = reconstruct(scene, config).metrics
    low, high = metrics[0.01], metrics[0.02]
    factor = high["ransac_threshold"] / low["ransac_threshold"]
    assert 1.4 < factor <= 4.0
    for m in (low, high):
        r = m["ransac_threshold"] / config.ransac_threshold
        spread.append(m["prior_weight"] / (config.prior_weight * r * r))
        assert m["robust_scale_px"] == pytest.approx(config.robust_scale * r * m["person_size_px"], rel=0.05)
    assert 1.0 < spread[0] <= MAX_SPREAD_FACTOR and spread[1] == pytest.approx(spread[0], rel=0.05)
    held = reconstruct(scene, config.replace(ransac_threshold_sigmas=0.0)).metrics
    assert held["prior_weight"] == pytest.approx(config.prior_weight * spread[1], rel=0.05)
    assert held["ransac_threshold"] == pytest.approx(config.ransac_threshold)
