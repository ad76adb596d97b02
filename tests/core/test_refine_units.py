"""The refinement's prior weight follows how well each person's views constrain it: a person
seen from all around (a dome) keeps ``prior_weight``, one on a hand-held tour's narrow arc gets
more, and that is more accurate against the simulated truth than one weight for both."""
from __future__ import annotations

import numpy as np
import pytest

import mvm.core.refine_units as units
from mvm.core.config import Config
from mvm.core.geometry import view_spread
from mvm.core.reconstruct import reconstruct
from mvm.metrics.poses import MATCH_DISTANCE_M, match_persons, pose_errors
from mvm.sim.simulate import SimConfig, simulate


def _cameras(angles_deg: np.ndarray, radius: float = 5.0) -> np.ndarray:
    """``(1, M, 3)`` camera centres at ``angles_deg`` around the origin, at the person's height."""
    a = np.radians(angles_deg)
    return radius * np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)[None]


def _person(centre: np.ndarray) -> np.ndarray:
    """``(1, 17, 3)`` joints scattered around ``centre`` (the centroid is what counts)."""
    offsets = np.random.default_rng(0).normal(scale=0.3, size=(17, 3))
    return (centre + offsets - offsets.mean(0))[None]


def test_view_spread_of_a_ring_an_arc_and_a_line():
    ring = _cameras(np.linspace(0, 360, 18, endpoint=False))
    arc = _cameras(np.linspace(-30, 30, 100))
    used = lambda c: np.ones(c.shape[:2], bool)  # noqa: E731
    origin = np.zeros((1, 3))
    assert view_spread(origin, ring, used(ring))[0] == pytest.approx(0.5)
    assert view_spread(origin, arc, used(arc))[0] == pytest.approx(np.radians(30) ** 2 / 3, rel=0.1)
    line = np.array([[[5.0, 0, 0], [10.0, 0, 0]]])
    assert view_spread(origin, line, used(line))[0] == pytest.approx(0.0, abs=1e-12)
    one = used(ring) & (np.arange(18) == 0)
    assert np.isnan(view_spread(origin, ring, one)[0])                 # a single view: unknown


def test_a_narrow_arc_gets_more_prior_weight_than_a_dome():
    config = Config()
    ring = _cameras(np.linspace(0, 360, 18, endpoint=False))
    arc = _cameras(np.linspace(-30, 30, 100))
    X = _person(np.zeros(3))
    dome = units.prior_weights(config, X, ring, np.ones(ring.shape[:2], bool))
    hand_held = units.prior_weights(config, X, arc, np.ones(arc.shape[:2], bool))
    assert dome[0] == pytest.approx(config.prior_weight)
    assert hand_held[0] == pytest.approx(units.MAX_SPREAD_FACTOR * config.prior_weight)
    # A view without an inlier does not count; a person without a joint gets the base weight.
    half = np.ones(ring.shape[:2], bool) & (np.arange(18) < 3)
    assert units.prior_weights(config, X, ring, half)[0] > config.prior_weight
    assert units.prior_weights(config, np.full_like(X, np.nan), ring, half)[0] == config.prior_weight



@pytest.mark.parametrize("half_arc_deg", [15.0, 45.0, 60.0, 75.0, 90.0, 180.0])
def test_the_weight_of_a_tour_follows_its_arc(half_arc_deg):
    """Cameras evenly along a horizontal arc of ±θ around a person at their height: the view
    spread is the mean of sin² over the arc, 1/2 − sin 2θ / (4θ) (the vertical, across every
    ray, is constrained fully); the weight is ``prior_weight`` times 1/2 over it, within 1 and
    ``MAX_SPREAD_FACTOR``: the setting from a half circle on, more the narrower the arc."""
    config = Config()
    theta = np.radians(half_arc_deg)
    cameras = _cameras(np.linspace(-half_arc_deg, half_arc_deg, 721))
    spread = 0.5 - np.sin(2 * theta) / (4 * theta)
    expected = config.prior_weight * np.clip(units.ALL_ROUND_SPREAD / spread, 1.0, units.MAX_SPREAD_FACTOR)
    weight = units.prior_weights(config, _person(np.zeros(3)), cameras, np.ones(cameras.shape[:2], bool))[0]
    assert weight == pytest.approx(expected, rel=0.01)
    narrower = _cameras(np.linspace(-half_arc_deg / 2, half_arc_deg / 2, 721))
    assert units.prior_weights(config, _person(np.zeros(3)), narrower, np.ones(narrower.shape[:2], bool))[0] >= weight
    if half_arc_deg >= 90:
        assert weight == pytest.approx(config.prior_weight, rel=0.01)

def _mpjpe(result, truth) -> float:
    pairs = match_persons(result.persons.keypoints3d, truth.poses3d, MATCH_DISTANCE_M)
    assert len(pairs) == len(truth.poses3d)
    return pose_errors(result.persons.keypoints3d, truth.poses3d, pairs)["mpjpe"]


def test_the_spread_weight_is_more_accurate_than_the_domes_on_a_hand_held_tour(monkeypatch):
    """The demo's scene (a 60° tour of six people): with the weight following the views' spread
    the poses are closer to the truth than with the dome's weight for every person. (One larger
    weight for every person would do as well on this scene alone, 7.5e-4 gives 3.19 mm against
    3.20; the rule is what lets a dome keep the small weight it needs at the same setting.)"""
    scene, truth = simulate(SimConfig(seed=0))
    config = Config()
    following = _mpjpe(reconstruct(scene, config), truth)
    monkeypatch.setattr(units, "MAX_SPREAD_FACTOR", 1.0)
    one_weight = _mpjpe(reconstruct(scene, config), truth)
    assert following < one_weight - 1e-4
