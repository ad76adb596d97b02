"""Each baseline solves small cases whose answer is known; the registry's one interface."""
from __future__ import annotations

import numpy as np
import pytest

from mvm.core.config import Config
from mvm.core.matching.baselines import (
    BaselineConfig,
    dong_groups,
    hungarian_groups,
    project_block_stochastic,
    shortest_path_groups,
)
from mvm.core.matching.registry import AFFINITIES, MATCHERS, affinity_matrix, get_matcher, match_with
from mvm.metrics.poses import matching_precision_recall
from mvm.sim.simulate import SimConfig, simulate

from helpers import standing_poses


def _blocks(V=6, G=3, seed=0, missing=()):
    """Affinities of G people over V views: 0.45 within a person, about 0.02 across."""
    rng = np.random.default_rng(seed)
    view = np.repeat(np.arange(V), G)
    person = np.tile(np.arange(G), V)
    keep = np.array([(v, g) not in missing for v, g in zip(view, person)])
    view, person = view[keep], person[keep]
    N = len(view)
    order = rng.permutation(N)                       # poses of a frame in random order
    view, person = view[order], person[order]
    A = np.where(person[:, None] == person[None], 0.45, 0.02) + rng.uniform(0, 0.02, (N, N))
    A = (A + A.T) / 2
    A[view[:, None] == view[None]] = 0
    return A, rng.uniform(0.5, 1, N), view, person


def _partition(groups, person):
    return sorted(sorted(person[g].tolist()) for g in groups)


@pytest.mark.parametrize("solver", [
    lambda A, s, v: hungarian_groups(A, s, v),
    lambda A, s, v: shortest_path_groups(A, s, v),
    lambda A, s, v: dong_groups(A, s, v),
])
def test_each_baseline_recovers_a_block_structure(solver):
    A, score, view, person = _blocks(missing={(2, 1), (3, 1)})
    groups = solver(A, score, view)
    assert _partition(groups, person) == [[0] * 6, [1] * 4, [2] * 6]
    for g in groups:
        assert len(np.unique(view[g])) == len(g)


def test_sequential_matching_chains_errors_that_the_whole_matrix_avoids():
    # Person 0 and 1 look alike between consecutive frames 2 -> 3 (a swap), but every other
    # pair of frames tells them apart: the frame-to-frame Hungarian follows the swap, the
    # multi-way optimization does not.
    A, score, view, person = _blocks(V=6, G=2, seed=1)
    for a in np.flatnonzero(view == 2):
        for b in np.flatnonzero(view == 3):
            A[a, b] = A[b, a] = 0.45 if person[a] != person[b] else 0.02
    hung = hungarian_groups(A, score, view)
    dong = dong_groups(A, score, view)
    assert matching_precision_recall(hung, person)[0] < 0.7
    assert _partition(dong, person) == [[0] * 6, [1] * 6]


def test_gaps_and_links_below_threshold():
    A, score, view, person = _blocks(V=6, G=1, missing={(2, 0), (3, 0)})
    assert len(hungarian_groups(A, score, view, max_gap_frames=3)) == 1
    assert len(hungarian_groups(A, score, view, max_gap_frames=1)) == 2
    assert len(shortest_path_groups(A, score, view, max_gap_frames=1)) == 2
    assert len(shortest_path_groups(A, score, view, link_affinity=0.49)) == len(view)


def test_block_projection_bounds_column_sums():
    rng = np.random.default_rng(0)
    view = np.repeat(np.arange(4), 3)
    X = rng.uniform(0, 1, (12, 12))
    P = project_block_stochastic(X, np.array([0, 3, 6, 9]), steps=20)
    blocks = P.reshape(12, 4, 3).sum(-1)                                  # rows per view-block
    assert (P.reshape(4, 3, 12).sum(1) <= 1 + 1e-9).all()                # columns
    assert (blocks <= 1 + 1e-3).all()
    assert (P <= X + 1e-12).all() and len(view) == 12


def test_registry_names_and_errors():
    assert set(MATCHERS) == {"mvm", "hungarian", "shortest_path", "dong"}
    assert set(AFFINITIES) == {"mse", "geo", "geo+app"}
    with pytest.raises(ValueError, match="known: mvm, hungarian, shortest_path, dong"):
        get_matcher("spectral")
    scene, _ = simulate(SimConfig.preset("clean", people=2, frames=8, seed=0), standing_poses())
    with pytest.raises(ValueError, match="known: mse, geo, geo\\+app"):
        affinity_matrix(scene, Config(), "cosine")


def test_every_method_on_a_simulated_scene():
    scene, truth = simulate(SimConfig.preset("clean", people=3, frames=20, seed=3), standing_poses())
    config = Config(refine=False)
    for method in MATCHERS:
        groups = match_with(scene, config, method, "geo+app", BaselineConfig(dong_max_iterations=100))
        for g in groups:
            assert len(np.unique(scene.poses.view[g])) == len(g) >= config.min_group_size
        precision, recall = matching_precision_recall(groups, truth.person)
        assert precision >= 0.95, (method, precision)
        assert recall >= 0.5, (method, recall)
