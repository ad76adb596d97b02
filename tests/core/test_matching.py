"""Algorithm 1 on constructed affinities and on a hard constructed scene."""
from __future__ import annotations

import numpy as np
import pytest

from mvm.core.affinity import affinity, epipolar_distance
from mvm.core.geometry import project
from mvm.core.matching import greedy_groups
from mvm.core.scene import Poses2D
from mvm.metrics.poses import matching_precision_recall

from helpers import STANDING, random_cameras


def test_greedy_recovers_block_structure():
    rng = np.random.default_rng(0)
    V, G = 8, 3
    view = np.repeat(np.arange(V), G)
    person = np.tile(np.arange(G), V)
    A = np.where(person[:, None] == person[None], 0.45, 0.02) + rng.uniform(0, 0.02, (V * G, V * G))
    A = (A + A.T) / 2
    A[view[:, None] == view[None]] = 0
    groups = greedy_groups(A, rng.uniform(0.5, 1, V * G), view, tau=0.2)
    assert sorted(sorted(person[g].tolist()) for g in groups) == [[g] * V for g in range(G)]
    for g in groups:
        assert len(np.unique(view[g])) == len(g)


def test_seed_is_most_confident_and_threshold_stops_growth():
    view = np.array([0, 1, 2])
    A = np.array([[0, 0.4, 0.1], [0.4, 0, 0.1], [0.1, 0.1, 0]])
    groups = greedy_groups(A, np.array([0.5, 0.9, 0.7]), view, tau=0.2)
    assert groups[0][0] == 1 and sorted(groups[0]) == [0, 1]
    assert [g.tolist() for g in groups[1:]] == [[2]]


def test_undefined_affinity_neither_supports_nor_contradicts():
    view = np.array([0, 1, 2])
    A = np.array([[0, 0.4, np.nan], [0.4, 0, 0.3], [np.nan, 0.3, 0]])
    groups = greedy_groups(A, np.array([0.9, 0.8, 0.7]), view, tau=0.25)
    assert sorted(groups[0].tolist()) == [0, 1, 2]


def _close_pair_scene(seed: int, separation: float):
    """Two people side by side, same pose and height, seen by a 50-frame horizontal arc: the
    epipolar lines are nearly horizontal and run through both people."""
    rng = np.random.default_rng(seed)
    V = 50
    cams = random_cameras(rng, V, arc_deg=70)
    axis = np.cross(cams.centers.mean(0) / np.linalg.norm(cams.centers.mean(0)), [0, 0, 1.0])
    people = np.stack([STANDING + separation / 2 * axis, STANDING - separation / 2 * axis])
    uv, _ = project(people[None], cams.P[:, None])
    uv += rng.normal(0, 2.0, uv.shape)
    kp = np.concatenate([uv, rng.uniform(0.6, 1.0, uv.shape[:-1] + (1,))], -1).reshape(2 * V, 17, 3)
    view = np.repeat(np.arange(V), 2)
    return cams, Poses2D(kp, view, np.arange(2 * V), kp[..., 2].mean(-1)), np.tile([0, 1], V)


def test_mean_normalization_does_not_merge_close_people():
    for seed in range(3):
        cams, poses, person = _close_pair_scene(seed, separation=0.45)
        D = epipolar_distance(cams, poses.keypoints, poses.view, 0.1, 0.01, 3)
        A = affinity(D, 1.0)
        groups = greedy_groups(A, poses.score, poses.view, tau=0.2, min_group_size=3)
        precision, recall = matching_precision_recall(groups, person)
        assert precision >= 0.99, (seed, precision)
        assert recall >= 0.9, (seed, recall)
        # A threshold on the un-normalized sum (τ times the group size reached so far is not
        # what the paper's pseudo-code compares) would accept the neighbour: the sum of a
        # long group exceeds τ for any candidate.
        sums = A[groups[0]][:, person == 1 - person[groups[0][0]]].sum(0)
        assert (np.nan_to_num(sums) > 0.2).any()


def _rig_instants(rng: np.random.Generator, instants: int = 12):
    """1 to 4 people per instant seen by 5 cameras, some detections missed: cameras, poses
    (with their instant), the person of each pose."""
    cams = random_cameras(rng, 5, arc_deg=300)
    keypoints, view, instant, person = [], [], [], []
    for t in range(instants):
        G = int(rng.integers(1, 5))
        people = STANDING[None] + np.array([[2.0 * g - 3, rng.uniform(-1, 1), 0] for g in range(G)])[:, None]
        uv, _ = project(people[None], cams.P[:, None])                 # (V, G, 17, 2)
        seen = rng.uniform(size=(5, G)) < 0.8                                # some people missed
        kp = np.concatenate([uv + rng.normal(0, 1.0, uv.shape), np.ones(uv.shape[:-1] + (1,))], -1)[seen]
        keypoints.append(kp)
        view += np.nonzero(seen)[0].tolist()
        person += np.nonzero(seen)[1].tolist()
        instant += [t] * len(kp)
    poses = Poses2D(np.concatenate(keypoints), np.array(view), np.arange(len(view)), rng.uniform(0.5, 1, len(view)),
                    instant=np.array(instant))
    return cams, poses, np.array(person)


def test_instants_matched_together_as_each_alone():
    """The instants of a rig matched in one padded affinity and one grouping advancing in all
    of them give each instant's own affinity and groups, and the groups are the people."""
    from mvm.core.affinity import block_pose_affinity, pose_affinity
    from mvm.core.config import Config
    from mvm.core.matching.greedy import greedy_groups_blocks

    rng = np.random.default_rng(4)
    cams, poses, person = _rig_instants(rng)
    config = Config()
    blocks = poses.blocks()
    index = np.full((len(blocks), max(map(len, blocks))), -1)
    for b, rows in enumerate(blocks):
        index[b, :len(rows)] = rows
    A = block_pose_affinity(cams, poses, index, config)
    pad = index < 0
    together = greedy_groups_blocks(A, np.where(pad, 0, poses.score[index]), np.where(pad, -1, poses.view[index]),
                                    config.tau, config.min_pose_score)
    for b, rows in enumerate(blocks):
        alone = pose_affinity(cams, poses.subset(rows), config)
        n = len(rows)
        assert np.allclose(A[b, :n, :n], alone, rtol=1e-5, atol=1e-9, equal_nan=True)   # float32 rounding
        assert (A[b][pad[b]] < 1e-30).all() and (A[b][:, pad[b]] < 1e-30).all()
        expected = greedy_groups(alone, poses.score[rows], poses.view[rows], config.tau, config.min_pose_score)
        assert [g.tolist() for g in together[b]] == [g.tolist() for g in expected]
        assert sorted(sorted(person[rows[g]].tolist()) for g in together[b]) == \
            sorted([p] * int((person[rows] == p).sum()) for p in np.unique(person[rows]))


def test_match_batches_instants_and_matches_a_large_instant_alone(monkeypatch):
    """However the instants are batched (an instant too large for a batch is matched as a
    scene), the groups are the same and come instant by instant."""
    import mvm.core.pipeline as pipeline
    from mvm.core.config import Config

    cams, poses, _ = _rig_instants(np.random.default_rng(5), instants=8)
    batched = pipeline.match(cams, poses, Config())
    monkeypatch.setattr(pipeline, "MATCH_BATCH_PAIRS", 16)                   # every instant alone, as a scene
    alone = pipeline.match(cams, poses, Config())
    assert [g.tolist() for g in batched] == [g.tolist() for g in alone]
    assert np.all(np.diff([poses.instant[g[0]] for g in batched]) >= 0)
    assert all(len(np.unique(poses.instant[g])) == 1 for g in batched)
    used = np.concatenate(batched)
    assert len(np.unique(used)) == len(used) > len(poses) // 2


def _algorithm1(A, w, view, tau, min_score, min_group_size, release=False):
    """Algorithm 1 written plainly, one candidate at a time (the reference); with ``release`` a
    group too small gives its poses back, its seed no longer seeding."""
    available = [x for x in range(len(w)) if w[x] >= min_score]
    groups = []
    for seed in sorted(range(len(w)), key=lambda x: -w[x]):
        if seed not in available:
            continue
        available.remove(seed)
        group = [seed]
        while True:
            best, best_sum, best_weight = None, -np.inf, 0.0
            for x in available:
                if view[x] in {view[p] for p in group}:
                    continue
                total = sum(w[p] * np.nan_to_num(A[x, p]) for p in group)
                weight = sum(w[p] for p in group if not np.isnan(A[x, p]))
                if w[x] * total > best_sum:
                    best, best_sum, best_weight = x, w[x] * total, weight
            if best is None or best_weight == 0 or best_sum / w[best] < tau * best_weight:
                break
            group.append(best)
            available.remove(best)
        if len(group) >= min_group_size:
            groups.append(group)
        elif release:                             # too small: its poses may join later groups
            available = sorted(available + group)
    return groups


@pytest.mark.parametrize("release", [False, True])
def test_greedy_in_blocks_is_algorithm_1(release):
    """Random affinities with undefined pairs, repeated confidences and views, several blocks
    of different sizes at once: each block's groups are the reference's (groups too small given
    back with ``release``)."""
    from mvm.core.matching.greedy import greedy_groups_blocks

    rng = np.random.default_rng(6)
    sizes = rng.integers(0, 14, 9)
    n = sizes.max()
    A = rng.uniform(0, 0.5, (len(sizes), n, n)).astype(np.float32)
    A[rng.uniform(size=A.shape) < 0.15] = np.nan
    A = np.where(np.isnan(A) | np.isnan(A.transpose(0, 2, 1)), np.nan, (A + A.transpose(0, 2, 1)) / 2)
    w = rng.choice([0.3, 0.5, 0.8, 1.0], (len(sizes), n))
    view = rng.integers(0, 4, (len(sizes), n))
    pad = np.arange(n)[None] >= sizes[:, None]
    view[pad] = -1
    groups = greedy_groups_blocks(A, w, view, 0.22, min_score=0.4, min_group_size=3, release=release)
    for b, size in enumerate(sizes):
        expected = _algorithm1(A[b, :size, :size].astype(float), w[b, :size], view[b, :size], 0.22, 0.4, 3,
                               release)
        assert [g.tolist() for g in groups[b]] == expected
    assert sum(len(g) for g in groups) >= 3                                  # the case is not empty


@pytest.mark.parametrize("release", [False, True])
def test_one_block_groups_as_the_blocks_do(release):
    """A scene (one block, grouped on its own state) gets exactly the groups the batched
    grouping gives its block, and the reference's, over random affinities with ties."""
    from mvm.core.matching.greedy import greedy_groups_blocks

    rng = np.random.default_rng(7)
    checked = 0
    for _trial in range(20):
        n = int(rng.integers(1, 25))
        A = rng.uniform(0, 0.5, (n, n)).astype(np.float32)
        A[rng.uniform(size=A.shape) < 0.2] = np.nan
        A = np.where(np.isnan(A) | np.isnan(A.T), np.nan, (A + A.T) / 2)
        w = rng.choice([0.3, 0.5, 0.8, 1.0], n)
        view = rng.integers(0, 5, n)
        alone = greedy_groups(A, w, view, 0.2, min_score=0.4, min_group_size=2, release=release)
        # A second, empty block forces the batched path.
        blocks = greedy_groups_blocks(np.stack([A, np.zeros_like(A)]), np.stack([w, np.zeros(n)]),
                                      np.stack([view, np.full(n, -1)]), 0.2, min_score=0.4, min_group_size=2,
                                      release=release)
        assert [g.tolist() for g in alone] == [g.tolist() for g in blocks[0]] == \
            _algorithm1(A.astype(float), w, view, 0.2, 0.4, 2, release)
        assert all(g.dtype == np.intp for g in alone)
        checked += sum(len(g) for g in alone)
    assert checked > 20                                                      # the cases are not empty


def test_poses_in_too_few_views_make_no_group_and_are_not_matched(bank_poses):
    """The shortcut of :func:`mvm.core.pipeline.match` (eligible poses in fewer than
    ``min_group_size`` views make no group) gives what the grouping itself gives."""
    from mvm.core.affinity import pose_affinity
    from mvm.core.config import Config
    from mvm.core.matching import greedy_groups
    from mvm.core.pipeline import _may_group, match
    from mvm.sim.simulate import SimConfig, simulate

    scene, _ = simulate(SimConfig(people=2, frames=8, seed=2), bank_poses)
    poses = scene.poses
    for config in (Config(min_group_size=3), Config(min_group_size=2), Config(min_group_size=3, min_pose_score=0.9)):
        for views in ([0], [0, 1], [0, 1, 2], [2, 5, 7]):
            sub = poses.subset(np.flatnonzero(np.isin(poses.view, views)))
            grouped = greedy_groups(pose_affinity(scene.cameras, sub, config), sub.score, sub.view, config.tau,
                                    config.min_pose_score, config.min_group_size)
            if not _may_group(sub.view, sub.score, config):
                assert grouped == [] and match(scene.cameras, sub, config) == []
            assert [g.tolist() for g in match(scene.cameras, sub, config)] == [g.tolist() for g in grouped]
    assert not _may_group(np.array([0, 0, 1]), np.ones(3), Config(min_group_size=3))
    assert _may_group(np.array([0, 1, 2]), np.ones(3), Config(min_group_size=3))
    assert not _may_group(np.array([0, 1, 2]), np.array([1.0, 1.0, np.nan]), Config(min_group_size=3))


def test_a_person_whose_first_seed_closes_too_small_is_found_from_another():
    """Four cameras see one person; the most confident pose agrees with only one other well
    enough, so its group closes at two poses, under the three a group needs. Without
    ``release`` those two poses are spent and nobody is found; with it they join the group the
    next seed grows, and the person is found in all four views (the real 4-camera capture's
    noisiest instants)."""
    A = np.array([[0, 0.325, 0.177, 0.206],
                  [0.325, 0, 0.264, 0.136],
                  [0.177, 0.264, 0, 0.312],
                  [0.206, 0.136, 0.312, 0]], dtype=np.float32)
    w = np.array([0.92, 0.91, 0.90, 0.93])                     # pose 3 seeds first
    view = np.arange(4)
    assert greedy_groups(A, w, view, 0.2, min_group_size=3) == []
    found = greedy_groups(A, w, view, 0.2, min_group_size=3, release=True)
    assert [sorted(g.tolist()) for g in found] == [[0, 1, 2, 3]]
