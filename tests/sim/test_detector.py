"""The one detector error model: measured errors match its settings."""
from __future__ import annotations

import numpy as np
import pytest

from mvm.sim.detector import DetectorErrors, detect_people
from mvm.sim.people import STANDING
from mvm.sim.projection import image_size_of_people, project_people

from helpers import random_cameras


def _scene(V=40, G=4, seed=0):
    rng = np.random.default_rng(seed)
    cameras = random_cameras(rng, V, radius=6.0, arc_deg=60.0)
    people = np.stack([STANDING + [1.2 * g - 1.8, 0.3 * (g % 2), 0.0] for g in range(G)])
    uv, depth = project_people(cameras, people)
    return cameras, uv, depth


def _detect(errors, seed=1, **kw):
    cameras, uv, depth = _scene()
    found = detect_people(uv, depth, cameras.size, cameras.focal, errors, np.random.default_rng(seed), **kw)
    return cameras, uv, depth, found


def test_noise_and_dropout_follow_the_settings():
    errors = DetectorErrors(noise=0.02, dropout=0.1, occlusion=False, swap_prob=0.0, outlier_joint_prob=0.0,
                            false_pose_rate=0.0)
    cameras, uv, depth, found = _detect(errors)
    assert (found.person >= 0).all() and len(found.person) == uv.shape[0] * uv.shape[1]
    true_uv = uv[found.view, found.person]                                          # (N, 17, 2)
    size = image_size_of_people(uv, np.ones(uv.shape[:3], bool))[found.view, found.person]
    present = found.keypoints[..., 2] > 0
    relative = (found.keypoints[..., :2] - true_uv)[present] / np.repeat(size[:, None], 17, 1)[present][:, None]
    assert relative.std() == pytest.approx(0.02, rel=0.1)
    assert 1 - present.mean() == pytest.approx(0.1, abs=0.03)


def test_swaps_outliers_and_false_poses():
    errors = DetectorErrors(noise=0.0, dropout=0.0, occlusion=False, swap_prob=0.2, outlier_joint_prob=0.05,
                            false_pose_rate=2.0)
    cameras, uv, depth, found = _detect(errors, seed=2)
    true = found.person >= 0
    V = uv.shape[0]
    assert (~true).sum() / V == pytest.approx(2.0, rel=0.3)
    error = np.linalg.norm(found.keypoints[true, :, :2] - uv[found.view[true], found.person[true]], axis=-1)
    mirrored = (error[:, 5] > 10) & (error[:, 6] > 10) & (error[:, 11] > 10) & (error[:, 12] > 10)
    assert mirrored.mean() == pytest.approx(0.2, abs=0.08)
    outlying = (error[~mirrored] > 1e-6).mean()
    assert outlying == pytest.approx(0.05, abs=0.025)


def _copied_from_own_view(found) -> float:
    """Fraction of the false poses that are a shifted copy of a true detection of their view."""
    hits = []
    for f in np.flatnonzero(found.person < 0):
        kept = found.keypoints[f, :, 2] > 0
        if kept.sum() < 3:                                   # mostly shifted out of the frame
            continue
        same = np.flatnonzero((found.view == found.view[f]) & (found.person >= 0))
        shift = found.keypoints[same][:, kept, :2] - found.keypoints[f, kept, :2]      # (C, K, 2)
        hits.append(bool((shift.std(axis=1).max(axis=1) < 1e-6).any()))
    return float(np.mean(hits))


def test_false_poses_from_the_view_or_the_scene():
    errors = DetectorErrors(noise=0.0, dropout=0.0, occlusion=False, swap_prob=0.0, outlier_joint_prob=0.0,
                            false_pose_rate=3.0)
    own = {}
    for source in ("view", "scene"):
        *_, found = _detect(errors, seed=3, false_poses_from=source)
        own[source] = _copied_from_own_view(found)
    assert own["view"] == 1.0 and own["scene"] < 0.5
    with pytest.raises(ValueError, match="false_poses_from"):
        _detect(errors, false_poses_from="frame")
    with pytest.raises(ValueError, match="dropout"):
        DetectorErrors(dropout=1.5)


def test_appearance_is_drawn_only_with_clothes():
    errors = DetectorErrors(false_pose_rate=0.5)
    *_, plain = _detect(errors, seed=4)
    clothes = np.full((4, 3), 0.5)
    *_, dressed = _detect(errors, seed=4, clothes=clothes, appearance_noise=0.0)
    assert plain.appearance is None and dressed.appearance.shape == (len(dressed.person), 3)
    np.testing.assert_allclose(dressed.appearance[dressed.person >= 0], 0.5)
