"""Long videos at linear cost: keyframes, windows, the triangulation of persons seen in many
views, and the whole pipeline on a video longer than its keyframes."""
from __future__ import annotations

import numpy as np
import pytest

from mvm.core.config import Config
from mvm.core.geometry import project
from mvm.core.keyframes import frame_windows, spread_views
from mvm.core.pipeline import keyframe_rows
from mvm.core.reconstruct import check_affinity_memory, reconstruct
from mvm.core.scene import Poses2D
from mvm.core.triangulate import gather_groups, ransac_triangulate, spread_slots
from mvm.errors import InputError
from mvm.eval.crowd import true_groups
from mvm.metrics.poses import matching_precision_recall
from mvm.sim.simulate import SimConfig, simulate

from helpers import STANDING, random_cameras, standing_poses


def test_keyframes_are_evenly_spread_along_the_video():
    views = np.arange(100)
    sequence = np.arange(100)[::-1].copy()                    # the views in reverse video order
    key = spread_views(views, 5, sequence, np.zeros((100, 3)))
    assert key.tolist() == [0, 25, 50, 74, 99] or key.tolist() == [0, 25, 49, 74, 99]
    assert spread_views(views[:4], 5, sequence, np.zeros((100, 3))).tolist() == [0, 1, 2, 3]


def test_keyframes_of_unordered_photos_are_spread_in_space():
    """Cameras on a line, most of them bunched at one end: farthest-point sampling takes the
    two ends and the lone ones, not the bunch."""
    x = np.concatenate([np.linspace(0, 0.1, 20), [5.0, 10.0]])
    centers = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    key = spread_views(np.arange(22), 3, None, centers)
    assert set(key.tolist()) == {0, 20, 21} or set(key.tolist()) == {19, 20, 21}
    assert 20 in key and 21 in key


def test_windows_are_runs_of_consecutive_frames():
    view = np.array([0, 0, 1, 2, 2, 3, 4, 5, 9])
    assert frame_windows(view, 2, None).tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 3]
    assert frame_windows(view, 2, np.arange(10)[::-1].copy()).tolist() == [3, 3, 2, 2, 2, 1, 1, 0, 0]
    assert frame_windows(view, 10, None).max() == 0


def test_spread_slots_take_the_most_confident_slot_of_each_run():
    conf = np.zeros((2, 8, 17))
    conf[0, :, :] = np.array([0.5, 0.9, 0.1, 0.2, 0.8, 0.3, 0.4, 0.6])[:, None]
    conf[1, :3] = 1.0                                          # three slots only: all of them, padded
    slots = spread_slots(conf, 4)
    assert slots[0].tolist() == [1, 3, 4, 7]                    # runs {0,1}, {2,3}, {4,5}, {6,7}
    assert slots[1].tolist() == [0, 1, 2, -1]


def test_a_person_seen_in_many_views_triangulates_as_well_from_a_spread_subset():
    """400 views with 20 % outliers: hypotheses on 40 spread views, inliers among all 400."""
    rng = np.random.default_rng(1)
    cams = random_cameras(rng, 400, arc_deg=120)
    people = np.stack([STANDING, STANDING + [1.0, 0.2, 0.0]])
    uv, _ = project(people[None], cams.P[:, None])
    uv = uv + rng.normal(0, 0.5, uv.shape)
    outliers = rng.uniform(size=uv.shape[:-1]) < 0.2
    uv[outliers] += rng.uniform(60, 200, (outliers.sum(), 2))
    kp = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], -1).reshape(800, 17, 3)
    poses = Poses2D(kp, np.repeat(np.arange(400), 2), np.arange(800), np.ones(800))
    obs = gather_groups(cams, poses, [np.arange(0, 800, 2), np.arange(1, 800, 2)], 0.1)
    full = ransac_triangulate(obs, 0.08, 48, 2, 1.0, 0)                 # person sizes (10 px here)
    spread = ransac_triangulate(obs, 0.08, 48, 2, 1.0, 0, max_views=40)
    assert np.abs(spread.X - people).max() < 0.01
    assert np.abs(spread.X - full.X).max() < 0.002
    assert np.array_equal(spread.inliers, ~outliers.transpose(1, 0, 2) | full.inliers) or \
        (spread.inliers == full.inliers).mean() > 0.999


def _long_scene():
    return simulate(SimConfig.preset("realistic", people=4, frames=120, arc_deg=90, seed=3),
                    bank_poses=standing_poses())


def test_a_video_longer_than_its_keyframes_is_grouped_on_them_and_loses_nothing():
    scene, truth = _long_scene()
    config = Config(refine=False)
    rows = keyframe_rows(scene.cameras, scene.poses, config.replace(keyframes=30).for_driver("scene"))
    assert len(np.unique(scene.poses.view[rows])) == 30 and len(rows) < len(scene.poses) / 3
    assert keyframe_rows(scene.cameras, scene.poses, config.for_driver("scene")) is None     # 120 <= 150
    whole = reconstruct(scene, config)
    keyed = reconstruct(scene, config.replace(keyframes=30, max_triangulation_views=40))
    precision, recall = matching_precision_recall(keyed.persons.members, truth.person)
    assert len(keyed.persons) == len(whole.persons) == 4
    assert precision >= 0.995 and recall >= 0.995
    first = np.sort(keyed.persons.keypoints3d[:, 0, 0]), np.sort(whole.persons.keypoints3d[:, 0, 0])
    assert np.nanmax(np.abs(first[0] - first[1])) < 0.01


def test_the_papers_grouping_of_a_long_video_runs_on_its_keyframes_and_loses_nothing():
    """``association = "paper"``: Algorithm 1 on the keyframes, the other frames by one round of
    the assignment; as good as Algorithm 1 on every frame, whose affinity is refused here."""
    scene, truth = _long_scene()
    config = Config(refine=False, association="paper")
    whole = reconstruct(scene, config)
    rows = keyframe_rows(scene.cameras, scene.poses, config.replace(keyframes=30).for_driver("scene"))
    from mvm.core.affinity import affinity_bytes

    keyed = reconstruct(scene, config.replace(keyframes=30, max_affinity_bytes=affinity_bytes(len(rows), True)))
    (p_whole, r_whole), (p_keyed, r_keyed) = (matching_precision_recall(r.persons.members, truth.person)
                                              for r in (whole, keyed))
    assert len(whole.persons) == len(keyed.persons) == 4
    assert p_keyed >= min(p_whole, 0.995) and r_keyed >= r_whole - 0.005       # 1.0 / 0.96 here, keyed 1.0 / 0.98
    with pytest.raises(InputError, match="max_affinity_bytes"):
        reconstruct(scene, config.replace(max_affinity_bytes=affinity_bytes(len(rows), True)))


def test_only_the_keyframes_poses_count_against_the_affinity_limit():
    scene, truth = _long_scene()
    from mvm.core.affinity import affinity_bytes

    config = Config(keyframes=30, use_appearance=False).for_driver("scene")
    rows = keyframe_rows(scene.cameras, scene.poses, config)
    limit = affinity_bytes(len(rows), appearance=False)
    check_affinity_memory(scene, config.replace(max_affinity_bytes=limit), "s")            # fits
    with pytest.raises(InputError, match="keyframes"):
        check_affinity_memory(scene, config.replace(max_affinity_bytes=limit - 1), "s")
    check_affinity_memory(scene, config.replace(max_affinity_bytes=limit, association="paper"), "s")  # the same
    given = Config(refine=False, max_affinity_bytes=40 * 2**20)          # below any affinity, above the triangulation
    assert len(reconstruct(scene, given, groups=true_groups(truth.person)).persons) == 4


def test_windows_find_a_missed_person_and_drop_clusters_of_false_poses():
    """The poses no person explains, grouped window by window: a person all of whose poses are
    left over is found (in every window it is seen in); the false poses make no group."""
    from mvm.core.pipeline import match_windows

    scene, truth = _long_scene()
    left = np.flatnonzero((truth.person == 0) | (truth.person < 0))
    config = Config(keyframes=30).for_driver("scene")
    groups = match_windows(scene.cameras, scene.poses.subset(left), config)
    assert groups and all((truth.person[left[g]] == 0).mean() > 0.9 for g in groups)
    found = np.concatenate(groups)
    assert (truth.person[left[found]] == 0).sum() >= 0.8 * (truth.person == 0).sum()
    assert len(groups) <= 4                                               # at most one per window
