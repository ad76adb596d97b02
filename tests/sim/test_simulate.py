"""The simulator's ground truth is self-consistent; its features do what they say."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mvm.errors import InputError
from mvm.io.ground_truth import read_ground_truth, write_simulation
from mvm.io.trajectory import parse_trajectory, read_trajectory
from mvm.sim.projection import project_people
from mvm.sim.simulate import SimConfig, simulate

from helpers import SHARED_DATA, STANDING, standing_poses

BANK = standing_poses(40, seed=3)


def _labelled_bank():
    """Standing poses plus crude sitting and crouching ones (pelvis lowered), with labels."""
    sitting = STANDING.copy()
    sitting[:13, 2] -= 0.45
    sitting[13:15] += [0, 0.4, -0.05]
    crouching = STANDING.copy()
    crouching[:15, 2] *= 0.6
    poses = np.concatenate([BANK[:10], np.repeat(sitting[None], 5, 0), np.repeat(crouching[None], 5, 0)])
    poses[..., 2] -= poses[..., 2].min(axis=1, keepdims=True)
    return poses, np.array(["standing"] * 10 + ["sitting"] * 5 + ["crouching"] * 5)


def _exact(**overrides):
    return SimConfig.preset("clean", **overrides)


def test_clean_detections_are_exact_projections_of_the_truth():
    scene, truth = simulate(_exact(people=5, frames=25, seed=1), BANK)
    assert (truth.person >= 0).all() and (truth.merged_with < 0).all()
    uv, _ = project_people(scene.cameras, truth.poses3d)                         # (V, G, 17, 2)
    kp = scene.poses.keypoints
    expected = uv[scene.poses.view, truth.person]                                 # (N, 17, 2)
    present = kp[..., 2] > 0
    assert present.sum() > 1000
    assert np.abs(kp[..., :2][present] - expected[present]).max() < 1e-6
    # every true person is seen, and each in at most one pose per view
    pairs = np.stack([scene.poses.view, truth.person], 1)
    assert len(np.unique(pairs, axis=0)) == len(pairs)
    assert set(truth.person.tolist()) == set(range(5))


def _points_on_limbs(pose, samples=25):
    from mvm.sim.projection import OCCLUDER_LIMBS as _OCCLUDER_LIMBS

    t = np.linspace(0, 1, samples)[:, None, None]
    return (pose[_OCCLUDER_LIMBS[:, 0]] * (1 - t) + pose[_OCCLUDER_LIMBS[:, 1]] * t).reshape(-1, 3)


def test_occluded_joints_really_are_behind_someone():
    sim = _exact(people=8, frames=20, seed=4, crowd_radius=1.6, min_separation=0.6)
    scene, truth = simulate(sim, BANK)
    uv, depth = project_people(scene.cameras, truth.poses3d)
    W, H = sim.image_width, sim.image_height
    centers = scene.cameras.centers
    checked = 0
    for n in range(len(scene.poses)):
        v, g = scene.poses.view[n], truth.person[n]
        inside = (uv[v, g, :, 0] >= 0) & (uv[v, g, :, 0] < W) & (uv[v, g, :, 1] >= 0) & (uv[v, g, :, 1] < H)
        lost = inside & (scene.poses.keypoints[n, :, 2] == 0)
        for j in np.flatnonzero(lost):
            joint, camera = truth.poses3d[g, j], centers[v]
            ray = (joint - camera) / np.linalg.norm(joint - camera)
            others = np.concatenate([_points_on_limbs(truth.poses3d[o]) for o in range(len(truth.poses3d)) if o != g])
            along = (others - camera) @ ray                                         # distance along the ray
            off = np.linalg.norm((others - camera) - along[:, None] * ray, axis=1)  # distance from the ray
            in_front = along < np.linalg.norm(joint - camera) - 0.1
            assert (in_front & (off < 0.1)).any(), (n, j)
            checked += 1
    assert checked > 20


def test_without_occlusion_every_joint_in_the_frame_is_detected():
    sim = _exact(people=8, frames=15, seed=4, crowd_radius=1.6, min_separation=0.6, occlusion=False)
    scene, truth = simulate(sim, BANK)
    uv, depth = project_people(scene.cameras, truth.poses3d)
    inside = ((uv[..., 0] >= 0) & (uv[..., 0] < sim.image_width) & (uv[..., 1] >= 0)
              & (uv[..., 1] < sim.image_height))[scene.poses.view, truth.person]
    assert np.array_equal(scene.poses.keypoints[..., 2] > 0, inside)


def test_people_cut_by_the_frame_are_detected_with_their_visible_joints():
    sim = _exact(people=6, frames=15, seed=4, camera_distance=2.5, occlusion=False)
    scene, truth = simulate(sim, BANK)
    present = scene.poses.keypoints[..., 2] > 0
    partial = ~present.all(1)
    assert partial.sum() >= 5
    assert (present[partial].sum(1) >= 5).all()


def test_defaults_and_presets():
    default = SimConfig()
    detector = default.detector
    assert ((default.people, default.frames, detector.noise, detector.dropout, detector.false_pose_rate)
            == (6, 100, 0.008, 0.03, 0.1))
    assert default.postures is None and default.close_pairs == 0 and detector.merge_prob == 0.0
    hard, clean = SimConfig.preset("hard", people=4), SimConfig.preset("clean")
    assert (hard.people == 4
            and hard.detector.noise > SimConfig.preset("realistic").detector.noise > clean.detector.noise == 0)
    assert default.replace(noise=0.02, people=3).detector == dataclasses.replace(detector, noise=0.02)
    with pytest.raises(ValueError, match="known: clean, realistic, hard"):
        SimConfig.preset("medium")


def test_postures_close_pairs_and_no_intersections():
    poses, labels = _labelled_bank()
    sim = _exact(people=6, frames=10, seed=2, postures=(0.0, 1.0, 0.0), close_pairs=2)
    scene, truth = simulate(sim, poses, labels)
    assert truth.labels == ("sitting",) * 6
    sim = _exact(people=6, frames=10, seed=2, postures=(1.0, 0.0, 0.0), close_pairs=2)
    _, truth = simulate(sim, poses, labels)
    pelvis = truth.poses3d[:, 11:13, :2].mean(1)
    d = np.linalg.norm(pelvis[:, None] - pelvis[None], axis=-1) + np.eye(6) * 9
    assert (np.abs(d.min(1) - sim.close_distance) < 0.1).sum() >= 2
    joints = np.linalg.norm(truth.poses3d[:, None, :, None, :2] - truth.poses3d[None, :, None, :, :2], axis=-1)
    level = np.abs(truth.poses3d[:, None, :, None, 2] - truth.poses3d[None, :, None, :, 2]) < 0.3
    joints = np.where(level, joints, np.inf)
    joints[np.arange(6), np.arange(6)] = np.inf
    assert joints.min() >= sim.body_clearance - 1e-9


def test_merged_poses_take_the_lower_body_of_the_other_person():
    sim = _exact(people=6, frames=30, seed=5, merge_prob=1.0, close_pairs=3)
    scene, truth = simulate(sim, BANK)
    merged = np.flatnonzero(truth.merged_with >= 0)
    assert len(merged) > 0
    uv, _ = project_people(scene.cameras, truth.poses3d)
    for n in merged:
        kp, v = scene.poses.keypoints[n], scene.poses.view[n]
        lower = kp[11:, 2] > 0
        upper = kp[:11, 2] > 0
        assert np.abs(kp[11:, :2][lower] - uv[v, truth.merged_with[n], 11:][lower]).max() < 1e-6
        assert np.abs(kp[:11, :2][upper] - uv[v, truth.person[n], :11][upper]).max() < 1e-6
        # the other person has no separate pose in that view
        assert not ((scene.poses.view == v) & (truth.person == truth.merged_with[n])).any()


def test_lookalikes_wear_near_identical_clothes():
    scene, truth = simulate(_exact(people=5, frames=10, seed=6, lookalikes=1, appearance_noise=0.0), BANK)
    app = scene.poses.appearance[scene.poses.view == 0]
    who = truth.person[scene.poses.view == 0]
    a = app / np.linalg.norm(app, axis=1, keepdims=True)
    cos = a @ a.T
    twin = np.flatnonzero(who == 4)[0]
    others = np.delete(np.arange(len(who)), twin)
    assert cos[twin, others].max() > 0.99


def test_ground_truth_round_trip(tmp_path):
    sim = SimConfig.preset("hard", people=3, frames=12, seed=1)
    scene, truth = simulate(sim, BANK)
    path = write_simulation(tmp_path / "scene", scene, truth, sim)
    back = read_ground_truth(path)
    assert np.allclose(back.poses3d, truth.poses3d, atol=1e-6)
    assert np.array_equal(back.person, truth.person) and np.array_equal(back.merged_with, truth.merged_with)
    (tmp_path / "bad.json").write_text("{\"poses3d\": [1, 2]}")
    with pytest.raises(InputError, match="bad.json: person_of_annotation"):
        read_ground_truth(tmp_path / "bad.json")


GOOD_LINE = "1000 0.5 0.9 0.5 0.5 0 0 1 0 0 0 0 1 0 0 0 0 1 0"


def test_trajectory_reader_names_the_bad_line():
    trajectory = parse_trajectory(f"http://x\n{GOOD_LINE}\n{GOOD_LINE.replace('1000', '2000', 1)}\n")
    assert len(trajectory) == 2 and trajectory.R.shape == (2, 3, 3)
    with pytest.raises(InputError, match="line 3: expected 19 numbers, got 18"):
        parse_trajectory(f"http://x\n{GOOD_LINE}\n{GOOD_LINE[:-2]}\n", "cam.txt")
    with pytest.raises(InputError, match="line 2: not a number"):
        parse_trajectory(f"http://x\n{GOOD_LINE.replace('0.9', 'abc')}\n{GOOD_LINE}\n", "cam.txt")
    with pytest.raises(InputError, match="line 3: timestamps must increase"):
        parse_trajectory(f"http://x\n{GOOD_LINE}\n{GOOD_LINE}\n", "cam.txt")
    with pytest.raises(InputError, match="not a rotation"):
        parse_trajectory(f"http://x\n{GOOD_LINE.replace(' 1 0 0 0 0 1', ' 2 0 0 0 0 1', 1)}\n{GOOD_LINE}\n")


@pytest.mark.skipif(not (SHARED_DATA / "camera_trajectories").is_dir(),
                    reason="the real camera paths (../shared/data/camera_trajectories) are absent")
def test_real_trajectory_tour_spans_the_requested_arc():
    path = sorted((SHARED_DATA / "camera_trajectories").glob("*.txt"))[0]
    trajectory = read_trajectory(path)
    assert len(trajectory) == 16 and trajectory.url.startswith("http")
    sim = _exact(people=3, frames=40, seed=0, arc_deg=50.0, trajectory=str(path))
    scene, truth = simulate(sim, BANK)
    angles = np.unwrap(np.arctan2(scene.cameras.centers[:, 1], scene.cameras.centers[:, 0]))
    assert abs(np.degrees(np.ptp(angles)) - 50.0) < 8.0
    assert np.isclose(scene.cameras.K[0, 0, 0], np.median(trajectory.intrinsics[:, 0]) * sim.image_width)
    assert len(scene.poses) > 40


def test_a_crowd_of_another_size_keeps_the_density_of_the_preset():
    """The 'crowd' preset of 30 people: its disc and false poses follow the crowd, everyone
    stands at least min_separation from the others and at most max_separation from a neighbour."""
    from mvm.eval.crowd import pelvis_spacing
    from mvm.sim.simulate import crowd_radius

    sim = SimConfig.preset("crowd", people=30, frames=3, seed=1)
    assert (sim.crowd_radius, sim.detector.false_pose_rate) == (crowd_radius(30), pytest.approx(3.0))
    assert SimConfig.preset("crowd", people=30, crowd_radius=9.0).crowd_radius == 9.0
    assert SimConfig.preset("crowd").crowd_radius == crowd_radius(12)
    _, truth = simulate(sim)
    spacing = pelvis_spacing(truth.poses3d)
    assert len(truth.poses3d) == 30
    assert spacing.min() >= sim.min_separation - 1e-6 and spacing.max() <= sim.max_separation + 1e-6


def test_real_lengths_are_within_the_settings_bounds():
    """A two-minute video (3,600 frames at 30 frames/s) of 30 people is a valid scene."""
    sim = SimConfig.preset("realistic", people=30, frames=3600)
    assert (sim.people, sim.frames) == (30, 3600)
