"""RANSAC triangulation and refinement against constructed truth."""
from __future__ import annotations

import numpy as np
import pytest

from mvm.core.geometry import project
from mvm.core.scene import Poses2D
from mvm.core.triangulate import gather_groups, ransac_triangulate

from helpers import STANDING, random_cameras


def _observe(cams, people, rng, noise=0.0, outlier_frac=0.0):
    """Every person seen in every view: poses (V*G), groups, outlier mask (V, G, 17)."""
    V, G = len(cams), len(people)
    uv, _ = project(people[None], cams.P[:, None])                     # (V, G, 17, 2)
    uv = uv + rng.normal(0, noise, uv.shape) if noise else uv
    outliers = rng.uniform(size=uv.shape[:-1]) < outlier_frac
    uv[outliers] += rng.uniform(60, 200, (outliers.sum(), 2)) * rng.choice([-1, 1], (outliers.sum(), 2))
    kp = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], -1).reshape(V * G, 17, 3)
    view = np.repeat(np.arange(V), G)
    poses = Poses2D(kp, view, np.arange(V * G), np.ones(V * G))
    groups = [np.arange(g, V * G, G) for g in range(G)]
    return poses, groups, outliers


def test_ransac_ignores_planted_outliers():
    rng = np.random.default_rng(0)
    cams = random_cameras(rng, 30, arc_deg=90)
    people = np.stack([STANDING, STANDING + [1.0, 0.2, 0.0]])
    poses, groups, outliers = _observe(cams, people, rng, outlier_frac=0.3)
    obs = gather_groups(cams, poses, groups, 0.1)
    tri = ransac_triangulate(obs, 0.06, 64, 2, 1.0, rng)
    assert np.abs(tri.X - people).max() < 1e-6
    # The inliers are exactly the keypoints that were not corrupted.
    assert np.array_equal(tri.inliers, ~outliers.transpose(1, 0, 2))
    plain = ransac_triangulate(obs, 0.06, 64, 2, 1.0, rng, use_ransac=False)
    assert np.abs(plain.X - people).max() > 0.01


def test_small_parallax_is_left_unreconstructed():
    rng = np.random.default_rng(1)
    cams = random_cameras(rng, 10, arc_deg=1.0)                               # about 1-3° of parallax
    poses, groups, _ = _observe(cams, STANDING[None], rng, noise=0.5)
    obs = gather_groups(cams, poses, groups, 0.1)
    # The true parallax of every joint: the largest angle between its rays from the cameras.
    rays = STANDING[None] - cams.centers[:, None]                             # (V, 17, 3)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    truth = np.degrees(np.arccos(np.clip(np.einsum("ajc,bjc->jab", rays, rays), -1, 1))).max(axis=(1, 2))
    assert truth.max() < 5.0
    narrow = ransac_triangulate(obs, 0.06, 32, 2, truth.max() + 0.5, rng)
    assert np.isnan(narrow.X).all()
    assert np.allclose(narrow.parallax_deg[0], truth, atol=0.1)
    wide = ransac_triangulate(obs, 0.06, 32, 2, truth.min() - 0.5, rng)
    assert np.isfinite(wide.X).all()


@pytest.mark.parametrize("noise", [1.0, 3.0])
def test_refinement_lowers_error_and_stays_near_triangulation(noise):
    from mvm.core.prior import PosePrior
    from mvm.core.quality import reprojection_errors
    from mvm.core.refine import refine_poses

    rng = np.random.default_rng(2)
    cams = random_cameras(rng, 40, arc_deg=60)
    people = np.stack([STANDING, STANDING + [0.9, -0.3, 0.0]])
    poses, groups, _ = _observe(cams, people, rng, noise=noise)
    obs = gather_groups(cams, poses, groups, 0.1)
    tri = ransac_triangulate(obs, 0.09, 48, 2, 1.0, rng)
    refined = refine_poses(tri.X, obs.xy, obs.conf, obs.P, tri.inliers, PosePrior.load(), 10.0, 5.0)
    plain = refine_poses(tri.X, obs.xy, obs.conf, obs.P, tri.inliers, None, 0.0, 5.0)
    before = reprojection_errors(tri.X, obs.xy, obs.P)[tri.inliers]
    # Reprojection alone: the error can only go down. With the prior it trades a little of it.
    assert (reprojection_errors(plain.X, obs.xy, obs.P)[tri.inliers] ** 2).mean() <= (before**2).mean() + 1e-9
    after = reprojection_errors(refined.X, obs.xy, obs.P)[tri.inliers]
    assert (after**2).mean() <= 1.01 * (before**2).mean()
    assert refined.cost_after <= refined.cost_before
    # Well-observed joints (40 views) move by less than a centimetre.
    assert np.linalg.norm(refined.X - tri.X, axis=-1).max() < 0.01
    assert not refined.fallback.any()


def test_prior_pulls_a_narrow_baseline_pose_toward_the_truth():
    """With three views over 8°, depth is poorly constrained: at the default weight the prior
    makes the pose more plausible and closer to the truth; without it nothing improves much."""
    from mvm.core.config import Config
    from mvm.core.image_units import in_person_sizes
    from mvm.core.prior import PosePrior, canonicalize
    from mvm.core.refine import refine_poses

    rng = np.random.default_rng(5)
    cams = random_cameras(rng, 3, arc_deg=8)
    poses, groups, _ = _observe(cams, STANDING[None], rng, noise=2.0)
    obs = gather_groups(cams, poses, groups, 0.1)
    tri = ransac_triangulate(obs, 0.09, 16, 2, 0.5, rng)
    prior = PosePrior.load()
    config = Config()

    def error(X):
        return np.linalg.norm(STANDING - X[0], axis=-1).mean()

    xy, P = in_person_sizes(obs.xy, obs.P, obs.size)                         # the unit of the settings
    with_prior = refine_poses(tri.X, xy, obs.conf, P, tri.inliers, prior, config.prior_weight, config.robust_scale)
    without = refine_poses(tri.X, xy, obs.conf, P, tri.inliers, None, 0.0, config.robust_scale)
    assert prior.nll(canonicalize(with_prior.X))[0] < prior.nll(canonicalize(tri.X))[0] - 10
    assert error(with_prior.X) < 0.85 * error(tri.X)
    assert error(with_prior.X) < 0.85 * error(without.X)


def test_few_views_enumerate_every_pair_of_views():
    """With no more view pairs than hypotheses, every pair is tried: a joint whose only clean
    pair is one specific pair of views is found whatever the random draws."""
    from mvm.core.triangulate import _sample_pairs

    rng = np.random.default_rng(2)
    valid = rng.uniform(size=(30, 6, 17)) < 0.7                               # (P, M, J)
    a, b = _sample_pairs(valid, 15, rng)
    count = valid.sum(1)
    for p, j in zip(*np.nonzero(count >= 2)):
        pairs = {tuple(sorted(x)) for x in zip(a[p, j], b[p, j])}
        views = np.flatnonzero(valid[p, :, j])
        assert pairs == {(u, w) for u in views for w in views if u < w}
    # Three outliers in five views: only the pair of clean views explains the point.
    cams = random_cameras(rng, 5, arc_deg=90)
    poses, groups, _ = _observe(cams, STANDING[None], rng)
    kp = poses.keypoints.copy()
    kp[:3, :, :2] += rng.uniform(80, 200, (3, 17, 2))
    obs = gather_groups(cams, Poses2D(kp, poses.view, poses.ids, poses.score), groups, 0.1)
    tri = ransac_triangulate(obs, 0.03, 10, 2, 1.0, rng)
    assert np.abs(tri.X - STANDING).max() < 1e-6
    assert np.array_equal(tri.inliers[0], np.arange(5)[:, None].repeat(17, 1) >= 3)


def test_a_refit_with_unchanged_inliers_is_skipped_with_the_same_numbers(bank_poses, monkeypatch):
    import mvm.core.triangulate as tri_module
    from mvm.core.config import Config
    from mvm.core.pipeline import match, triangulate_groups
    from mvm.sim.simulate import SimConfig, simulate

    scene, _ = simulate(SimConfig(people=3, frames=10, seed=6), bank_poses)
    config = Config()
    groups = match(scene.cameras, scene.poses, config)
    solves = []
    real = tri_module.weighted_dlt
    monkeypatch.setattr(tri_module, "weighted_dlt", lambda *a: solves.append(1) or real(*a))
    _, reused = triangulate_groups(scene.cameras, scene.poses, groups, config)
    assert len(solves) < 3                                          # the inliers settled: a solve skipped
    monkeypatch.setattr(tri_module, "_refit", lambda terms, weights, previous: (weights, real(terms, weights)))
    _, always = triangulate_groups(scene.cameras, scene.poses, groups, config)
    np.testing.assert_array_equal(reused.X, always.X)
    np.testing.assert_array_equal(reused.inliers, always.inliers)
