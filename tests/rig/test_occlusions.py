"""Limb joints through long occlusions of a rig's tracks (mvm.rig.occlusions), against a simulated
capture whose occlusions the test makes: a wrist hidden from every view but one, another from
every view, for 25 instants."""
import numpy as np
import pytest

from mvm.core.camera import project_views
from mvm.core.completion import INFERRED, OBSERVED
from mvm.core.config import Config
from mvm.core.keypoints import INDEX
from mvm.metrics.poses import match_persons
from mvm.rig.instants import reconstruct_instants, rig_poses
from mvm.rig.occlusions import rays
from mvm.rig.options import RigOptions
from mvm.rig.reconstruct_rig import completion_prior, instants_config, track_and_complete
from mvm.sim.rig import ring_cameras
from mvm.sim.rig_scene import RigSimConfig, simulate_rig

HIDDEN = range(30, 55)                          # instants
#: (person, joint, views left seeing it)
OCCLUSIONS = ((0, INDEX["right_wrist"], 1), (1, INDEX["left_wrist"], 0))


def _hide(sim):
    """Drop the occluded joints' keypoints in all views but the first ``left`` of them."""
    for g, j, left in OCCLUSIONS:
        rows = (sim.person == g) & np.isin(sim.frame, HIDDEN) & (sim.camera >= left)
        sim.keypoints[rows, j] = 0.0


def _run(sim, options):
    config = Config()
    prior = completion_prior(config)
    det = rig_poses(sim.keypoints, sim.frame, sim.camera, sim.score)
    cameras = sim.calibration.cameras
    persons = reconstruct_instants(cameras, det, instants_config(config), prior)
    _, persons, X, flags = track_and_complete(persons, options, prior, config, det, cameras)
    found = {}                                   # (person, joint) -> [(instant, error, flag, score)]
    around = []
    for t in HIDDEN:
        rows = np.flatnonzero(persons.instant == t)
        for p, g in match_persons(X[rows], sim.poses3d[t], 0.5):
            q = rows[p]
            d = np.linalg.norm(X[q] - sim.poses3d[t, g], axis=-1)
            for gg, j, _ in OCCLUSIONS:
                if gg == g:
                    found.setdefault(g, []).append((t, d[j], flags[q, j], persons.scores[q, j]))
                    around += d[[j - 2, j - 4]][flags[q, [j - 2, j - 4]] == OBSERVED].tolist()   # elbow, shoulder
    return found, np.mean(around)


@pytest.fixture(scope="module")
def runs():
    sim = simulate_rig(RigSimConfig(cameras=5, people=2, frames=90, distortion=0.0, seed=4))
    _hide(sim)
    return _run(sim, RigOptions(frame_rate=30.0)), _run(sim, RigOptions(frame_rate=30.0, occlusion_max_gap=0))


def test_hidden_wrists_are_inferred_near_the_truth(runs):
    (after, around), (before, _) = runs
    for g, _, left in OCCLUSIONS:
        t, error, flag, score = (np.array(v) for v in zip(*after[g]))
        assert len(t) >= 0.9 * len(HIDDEN)
        assert (flag == INFERRED).all()
        assert ((score > 0) & (score <= 1)).all()
        bound = 0.025 if left else 0.045                     # metres; the joints around: ~0.006
        assert error.mean() < bound, (g, error.mean(), around)
        assert error.mean() < np.mean([e for _, e, _, _ in before[g]])  # better than interpolation


def test_confidence_falls_towards_the_middle_of_an_unseen_gap(runs):
    (after, _), _ = runs
    g = next(g for g, _, left in OCCLUSIONS if left == 0)
    t, _, _, score = (np.array(v) for v in zip(*after[g]))
    middle = np.abs(t - np.mean(HIDDEN)) < 4
    ends = (t == HIDDEN[0]) | (t == HIDDEN[-1])
    assert score[middle].max() < score[ends].min()


def test_rays_pass_through_the_points_they_see():
    cameras = ring_cameras(4)
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.5, 0.5, (2, 17, 3)) + np.array([0, 0, 1.0])
    uv, _ = project_views(cameras, points)                                     # (V, Q, 17, 2)
    xy = uv.transpose(1, 0, 2, 3)
    conf = np.ones(xy.shape[:-1])
    conf[0, 1, 3] = 0.0
    origin, direction = rays(xy, conf, cameras)
    along = ((points[:, None] - origin) * direction).sum(-1, keepdims=True)
    miss = np.linalg.norm(points[:, None] - origin - along * direction, axis=-1)
    assert np.nanmax(miss) < 1e-9 and (along[np.isfinite(along)] > 0).all()
    assert np.isnan(origin[0, 1, 3]).all() and np.isfinite(origin).sum() == (conf > 0).sum() * 3
