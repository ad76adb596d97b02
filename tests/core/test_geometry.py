"""Geometry properties on constructed cameras and points."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mvm.core.affinity import epipolar_distance
from mvm.core.geometry import project, triangulate_dlt

from helpers import random_cameras

seeds = st.integers(0, 2**31 - 1)


@settings(max_examples=60, deadline=None)
@given(seeds, st.integers(2, 12))
def test_dlt_recovers_exact_point(seed, views):
    rng = np.random.default_rng(seed)
    cams = random_cameras(rng, views, arc_deg=rng.uniform(20, 180))
    X = rng.uniform([-1, -1, 0], [1, 1, 2])
    uv, _ = project(X, cams.P)
    weights = rng.uniform(0.2, 1.0, views)
    estimate = triangulate_dlt(uv, cams.P, weights)
    assert np.linalg.norm(estimate - X) < 1e-6


def test_dlt_needs_two_weighted_views():
    rng = np.random.default_rng(1)
    cams = random_cameras(rng, 3)
    uv, _ = project(np.array([0.1, 0.2, 1.0]), cams.P)
    assert np.isnan(triangulate_dlt(uv, cams.P, np.array([1.0, 0, 0]))).all()


def test_epipolar_distance_zero_for_same_person_and_resolution_invariant():
    rng = np.random.default_rng(3)
    cams = random_cameras(rng, 5)
    person = rng.uniform([-0.5, -0.5, 0], [0.5, 0.5, 1.8], size=(17, 3))
    other = person + np.array([0.0, 0.0, 0.3])                                # a head taller
    uv, _ = project(np.stack([person, other])[None], cams.P[:, None, None])    # (V, 2, 17, 2)
    kp = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], -1).reshape(10, 17, 3)
    view = np.repeat(np.arange(5), 2)
    D = epipolar_distance(cams, kp, view, 0.1, 0.01)
    same = (np.arange(10)[:, None] % 2 == np.arange(10)[None] % 2) & (view[:, None] != view[None])
    assert np.abs(D[same]).max() < 1e-3
    assert D[~same & (view[:, None] != view[None])].min() > 0.5
    assert np.isinf(D[view[:, None] == view[None]]).all()
    # The same scene at 3× the resolution gives the same D (units of the focal length).
    from mvm.core.scene import Cameras

    S = np.diag([3.0, 3.0, 1.0])
    big = Cameras(S @ cams.K, cams.R, cams.t, cams.size * 3, cams.names)
    kp3 = kp.copy()
    kp3[..., :2] *= 3
    D3 = epipolar_distance(big, kp3, view, 0.1, 0.01)
    finite = np.isfinite(D)
    assert np.allclose(D[finite], D3[finite], rtol=1e-4, atol=1e-4)
