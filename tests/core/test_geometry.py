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
    uv, _ = project(np.stack([person, other])[None], cams.P[:, None])    # (V, 2, 17, 2)
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


def _packed(N: np.ndarray) -> np.ndarray:
    from mvm.core.geometry import PACKED_4X4

    return np.stack([N[..., i, j] for i, j in PACKED_4X4])


def _angle_to(v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Angle (radians, to first order) between unit vectors up to sign. ``(..., 4)`` each."""
    return np.minimum(np.linalg.norm(v - w, axis=-1), np.linalg.norm(v + w, axis=-1))


def test_smallest_eigenvector_matches_eigh_on_random_psd_matrices():
    from mvm.core.geometry import smallest_eigenvector

    rng = np.random.default_rng(0)
    A = rng.normal(size=(2000, 6, 4)) * rng.uniform(1e-3, 1e3, (2000, 1, 1))     # any scale
    N = A.transpose(0, 2, 1) @ A
    values, vectors = np.linalg.eigh(N)
    v = smallest_eigenvector(_packed(N))
    assert np.allclose(np.linalg.norm(v, axis=-1), 1.0)
    # The error of an eigenvector is bounded by rounding over the eigen-gap (as for eigh).
    gap = (values[:, 1] - values[:, 0]) / values[:, 3]
    assert (_angle_to(v, vectors[..., 0]) <= 1e-9 + 1e-13 / gap).all()


def test_smallest_eigenvector_on_nearly_degenerate_matrices():
    """Rank 3 (an exact DLT), a nearly repeated smallest eigenvalue (two nearly parallel
    rays), rank 2 (two equal views) and non-finite input: the certified vectors are eigh's,
    the others are eigh's own answer or NaN."""
    from mvm.core.geometry import smallest_eigenvector

    rng = np.random.default_rng(1)
    Q = np.linalg.qr(rng.normal(size=(400, 4, 4)))[0]
    spectra = np.array([[0.0, 1.0, 2.0, 3.0], [1e-12, 1e-3, 0.5, 1.0], [1e-8, 1e-8 + 1e-14, 1.0, 2.0],
                        [0.0, 0.0, 1.0, 1.0]])
    values = np.repeat(spectra, 100, axis=0)
    N = np.einsum("nij,nj,nkj->nik", Q, values, Q)
    v = smallest_eigenvector(_packed(N))
    angle = _angle_to(v, Q[..., 0])
    assert (angle[:200] < 1e-8).all()                                        # well separated: exact
    # Repeated smallest eigenvalue: any unit vector of the smallest eigenspace is right.
    span = np.einsum("nij,nj->ni", Q[200:].transpose(0, 2, 1), v[200:])     # coordinates in the eigenbasis
    assert (np.linalg.norm(span[:, 2:], axis=-1) < 1e-6).all()
    assert np.allclose(np.linalg.norm(v, axis=-1), 1.0)
    broken = _packed(N[:3]).copy()
    broken[0, 1] = np.nan
    out = smallest_eigenvector(broken)
    assert np.isnan(out[1]).all() and np.isfinite(out[[0, 2]]).all()


def test_smallest_eigenvector_in_chunks_is_elementwise(monkeypatch):
    """Solved a few matrices at a time (chunks that split the batch's axes unevenly), a batch
    of shape (10, 7, 9) gets the same vectors as all at once, and eigh's."""
    from mvm.core import geometry

    rng = np.random.default_rng(2)
    A = rng.normal(size=(7, 9, 6, 4))
    N = A.swapaxes(-1, -2) @ A
    N[3, 4] = np.nan                                                         # one unsolvable matrix
    whole = geometry.smallest_eigenvector(_packed(N.reshape(-1, 4, 4)).reshape(10, 7, 9))
    monkeypatch.setattr(geometry, "NULL_VECTOR_CHUNK", 5)
    chunked = geometry.smallest_eigenvector(_packed(N.reshape(-1, 4, 4)).reshape(10, 7, 9))
    assert chunked.shape == (7, 9, 4)
    assert np.array_equal(whole, chunked, equal_nan=True)
    assert np.isnan(chunked[3, 4]).all()
    ok = np.ones((7, 9), dtype=bool)
    ok[3, 4] = False
    assert (_angle_to(chunked[ok], np.linalg.eigh(N[ok])[1][..., 0]) < 1e-8).all()
    assert geometry.smallest_eigenvector(np.zeros((10, 0))).shape == (0, 4)
