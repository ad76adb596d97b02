"""Memory bounded before it is taken: the duplicate test of thousands of candidate persons and
the triangulation of persons seen in thousands of frames work in chunks (the same answer as all
at once), and a triangulation larger than ``max_affinity_bytes`` is refused in one line naming
the setting, before its arrays exist."""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import mvm.core.duplicates as duplicates
import mvm.core.triangulate as triangulate
from mvm.core.config import Config
from mvm.core.duplicates import duplicate_pairs
from mvm.core.keypoints import FLIP_PERMUTATION, LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER
from mvm.core.pipeline import match, triangulate_groups, triangulation_bytes
from mvm.errors import InputError
from mvm.sim.simulate import SimConfig, simulate

from helpers import standing_poses


def _reference_pairs(X: np.ndarray, block: np.ndarray, limit: float, quantile: float) -> np.ndarray:
    """The duplicate test written pair by pair, as the docstring states it (numpy's quantile)."""
    P = len(X)
    close = np.zeros((P, P), dtype=bool)

    def torso(x):
        lengths = [np.linalg.norm(x[s] - x[h]) for s, h in ((LEFT_SHOULDER, LEFT_HIP), (RIGHT_SHOULDER, RIGHT_HIP))]
        lengths = [v for v in lengths if np.isfinite(v)]
        return np.mean(lengths) if lengths else np.nan

    def quartile_distance(a, b):
        d = np.linalg.norm(a - b, axis=-1)
        d = d[np.isfinite(d)]
        return np.quantile(d, quantile) if len(d) else np.nan

    for i in range(P):
        for j in range(P):
            if i != j and block[i] == block[j]:
                d = np.fmin(quartile_distance(X[i], X[j]), quartile_distance(X[i], X[j][FLIP_PERMUTATION]))
                close[i, j] = d < limit * np.fmax(torso(X[i]), torso(X[j]))
    return close


def _candidates(P: int, rng) -> np.ndarray:
    X = rng.normal(scale=0.3, size=(P, 17, 3))
    X[P // 2:] = X[:P - P // 2] + rng.normal(scale=0.01, size=(P - P // 2, 17, 3))    # duplicates
    X[rng.random((P, 17)) < 0.2] = np.nan
    return X


@pytest.mark.parametrize("quantile", [duplicates.ASSOCIATION_QUANTILE, duplicates.FINAL_QUANTILE])
@pytest.mark.parametrize("chunk", [1, 7, 2**14])
def test_duplicates_in_chunks_equal_the_pair_by_pair_test(monkeypatch, chunk, quantile):
    monkeypatch.setattr(duplicates, "DUPLICATE_PAIRS_CHUNK", chunk)
    rng = np.random.default_rng(3)
    for P, blocks in ((0, 1), (1, 1), (2, 1), (9, 1), (40, 6), (60, 60)):
        X = _candidates(P, rng)
        block = rng.integers(0, blocks, P)
        with np.errstate(invalid="ignore"):
            expected = _reference_pairs(X, block, 0.5, quantile)
        found = duplicate_pairs(X, block, 0.5, quantile)
        assert np.array_equal(found, expected), (P, blocks, chunk, quantile)
        if P >= 9 and blocks == 1:
            assert found.any()                                        # the test meets duplicates


def test_duplicates_of_many_candidates_take_bounded_memory():
    """600 candidate persons in one block: 359,400 pairs, 290 MB of differences at once;
    in chunks the working memory stays near the (P, P) answer."""
    X = _candidates(600, np.random.default_rng(0))
    tracemalloc.start()
    try:
        duplicate_pairs(X, np.zeros(600, dtype=int), 0.5)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 600**2 + 100 * 2**20, peak / 2**20


def test_a_triangulation_over_the_limit_is_refused_before_its_arrays_exist():
    scene, _ = simulate(SimConfig(people=3, frames=12, seed=2), bank_poses=standing_poses())
    groups = [np.arange(12) % len(scene.poses)] * 5000                         # 5000 candidates of 12 views
    need = triangulation_bytes(groups, 17, 48)
    assert need == 5000 * 12 * 17 * 49 * 64
    config = Config(max_affinity_bytes=need - 1)
    tracemalloc.start()
    try:
        with pytest.raises(InputError) as info:
            triangulate_groups(scene.cameras, scene.poses, groups, config)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    message = str(info.value)
    assert message.startswith("max_affinity_bytes: triangulating 5000 candidate persons of up to 12 views")
    assert "--set max_affinity_bytes=" in message and "\n" not in message
    assert peak < 2**20                                                          # nothing was allocated


def test_triangulation_memory_is_as_estimated():
    scene, _ = simulate(SimConfig(people=8, frames=40, seed=3), bank_poses=standing_poses())
    config = Config()
    groups = match(scene.cameras, scene.poses, config)
    tracemalloc.start()
    try:
        triangulate_groups(scene.cameras, scene.poses, groups, config)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    estimate = triangulation_bytes(groups, 17, config.ransac_hypotheses)
    assert 0.5 * estimate < peak <= estimate, (peak / 2**20, estimate / 2**20)
    triangulate_groups(scene.cameras, scene.poses, groups, config.replace(max_affinity_bytes=estimate))   # fits


@pytest.mark.parametrize("chunk", [1, 250_000])
def test_triangulation_in_chunks_equals_all_groups_at_once(monkeypatch, chunk):
    """Groups triangulated a few at a time (one, or for some calls two of these, per chunk)
    give the triangulation of all at once to the bit, and the same hypotheses (drawn for all
    groups at once, not chunk by chunk): RANSAC from random pairs and from every pair of views,
    on spread views of wider groups (with pairs of them drawn too), from previous poses, again at
    another threshold from the hypotheses kept, and without RANSAC."""
    scene, _ = simulate(SimConfig(people=6, frames=40, seed=4), bank_poses=standing_poses())
    base = Config()
    groups = match(scene.cameras, scene.poses, base)
    assert len(groups) >= 5

    def triangulations(config):
        obs, first = triangulate_groups(scene.cameras, scene.poses, groups, config, keep_hypotheses=True)
        again = triangulate_groups(scene.cameras, scene.poses, groups, config,
                                   threshold=np.full(len(scene.poses), 0.05), again=(obs, first))[1]
        warm = triangulate_groups(scene.cameras, scene.poses, groups, config, initial=first.X,
                                  keep_hypotheses=True)[1]                 # an association round's
        return first, again, warm

    configs = (base, base.replace(ransac_hypotheses=12), base.replace(max_triangulation_views=8),
               base.replace(max_triangulation_views=8, ransac_hypotheses=12), base.replace(ransac=False))
    expected = [triangulations(c) for c in configs]
    monkeypatch.setattr(triangulate, "TRIANGULATION_CHUNK", chunk)
    for config, want in zip(configs, expected):
        for found, tri in zip(triangulations(config), want):
            assert np.isfinite(tri.X).any()
            assert np.array_equal(found.X, tri.X, equal_nan=True)
            for field in ("inliers", "valid", "parallax_deg", "threshold"):
                assert np.array_equal(getattr(found, field), getattr(tri, field)), field
            assert (found.hypotheses is None) == (tri.hypotheses is None)
            if tri.hypotheses is not None:
                for field in ("err", "ok", "point"):
                    assert np.array_equal(getattr(found.hypotheses, field), getattr(tri.hypotheses, field),
                                          equal_nan=True), field


def test_persons_seen_in_thousands_of_frames_are_triangulated_in_bounded_memory(monkeypatch):
    """Four people filmed for 3,000 frames, triangulated again from their previous poses (an
    association round): beyond the observations themselves, the working memory stays under
    twice theirs; all groups at once it was more than four times theirs (the DLT terms of every
    view of every person, 16 MB here, and their temporaries)."""
    scene, truth = simulate(SimConfig.preset("realistic", people=4, frames=3000, arc_deg=120, seed=1))
    groups = [np.flatnonzero(truth.person == g) for g in range(len(truth.poses3d))]
    config = Config()
    _, first = triangulate_groups(scene.cameras, scene.poses, groups, config)

    def working_memory() -> tuple[float, float]:
        tracemalloc.start()
        try:
            obs, tri = triangulate_groups(scene.cameras, scene.poses, groups, config, initial=first.X)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        held = sum(getattr(obs, f).nbytes for f in ("xy", "conf", "P", "normalized_xy", "Rt", "centers", "members",
                                                    "size"))
        assert np.isfinite(tri.X).all(-1).sum() > 0.9 * tri.X.shape[0] * tri.X.shape[1]
        return peak - held, held

    chunked, held = working_memory()
    monkeypatch.setattr(triangulate, "TRIANGULATION_CHUNK", 2**40)
    at_once, _ = working_memory()
    assert chunked < 2 * held < 0.5 * at_once, (chunked / 2**20, held / 2**20, at_once / 2**20)
