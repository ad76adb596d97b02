"""Two people triangulated as one: told apart by a bone no view sees whole, and split, against
simulated scenes whose true persons are known."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mvm.core.body_parts import body_parts, split_persons
from mvm.core.config import Config
from mvm.core.keypoints import BONES, pelvis
from mvm.core.pipeline import associate_poses, triangulate_groups
from mvm.metrics.poses import matching_precision_recall
from mvm.sim.simulate import SimConfig, simulate

#: Joints seen of the person behind (head and right arm); the other person shows the rest.
HEAD_AND_ARM = [0, 1, 2, 3, 4, 6, 8, 10]

#: Two people 0.45 m apart, filmed over 60 frames of a 120° arc.
PAIR = SimConfig.preset("realistic", people=2, frames=60, arc_deg=120, seed=0, close_pairs=1, close_distance=0.45)


@pytest.fixture(scope="module")
def pair():
    return simulate(PAIR)


def two_bodies(truth):
    """A person made of the head and right arm of one true person and the rest of the other,
    and inlier views that never see both parts: 10 views of each."""
    X = truth.poses3d[1].copy()
    X[HEAD_AND_ARM] = truth.poses3d[0][HEAD_AND_ARM]
    inliers = np.zeros((1, 20, 17), dtype=bool)
    inliers[0, :10, HEAD_AND_ARM] = True
    rest = np.setdiff1d(np.arange(17), HEAD_AND_ARM)
    inliers[0, 10:, rest] = True
    return X[None], inliers


def test_two_people_are_told_from_one_by_a_bone_no_view_sees_whole(pair):
    _, truth = pair
    assert np.linalg.norm(pelvis(truth.poses3d[0]) - pelvis(truth.poses3d[1])) == pytest.approx(0.45, abs=0.02)
    X, inliers = two_bodies(truth)
    label = body_parts(X, inliers, 5, 2.0)[0]
    head = label[HEAD_AND_ARM]
    assert (head == head[0]).all() and head[0] >= 0
    assert (np.delete(label, HEAD_AND_ARM) == 1 - head[0]).all()
    # One true person seen in the same two sets of views has bones of human proportion: one body.
    assert (body_parts(truth.poses3d[1][None], inliers, 5, 2.0) == -1).all()
    # The same two people, but views that see both parts: one body (a pose explains both).
    both = inliers.copy()
    both[0, :5] = True
    assert (body_parts(X, both, 5, 2.0) == -1).all()
    # Views that see both parts whole but for the ends of the bones between them (a real
    # person's sides seen from the middle of the arc): the long bone's ends are seen apart, the
    # two sets of joints are not: one body.
    crossing = {j for a, b in BONES if (a in HEAD_AND_ARM) != (b in HEAD_AND_ARM) for j in (a, b)}
    middle = np.zeros((1, 30, 17), dtype=bool)
    middle[:, :20] = inliers
    middle[0, 20:, [j for j in range(17) if j not in crossing]] = True
    assert (body_parts(X, middle, 5, 2.0) == -1).all()
    # A stray joint is not a person: a wrist far off, seen apart from its elbow.
    stray = truth.poses3d[1].copy()
    stray[10] += [0.0, 0.8, 0.0]
    alone = np.zeros((1, 20, 17), dtype=bool)
    alone[0, :15] = True
    alone[0, :15, 10] = False
    alone[0, 15:, 10] = True
    assert (body_parts(stray[None], alone, 5, 2.0) == -1).all()


def test_split_persons_gives_each_part_its_poses_and_joints(pair):
    _, truth = pair
    X, inliers = two_bodies(truth)
    members = np.arange(20)[None] + 100
    other = np.full((1, 17, 3), 1.0)
    slots = np.concatenate([np.arange(20)[None], members])
    out = split_persons([np.arange(5), members[0]], np.concatenate([other, X]),
                        np.concatenate([np.ones_like(inliers), inliers]), slots, 5, 2.0)
    assert out is not None
    groups, X_out, person, part = out
    assert person.tolist() == [0, 1, 1] and part.tolist() == [-1, 0, 1]
    assert sorted(map(tuple, (np.sort(g).tolist() for g in groups[1:]))) == [tuple(range(100, 110)),
                                                                            tuple(range(110, 120))]
    assert np.array_equal(X_out[0], other[0])
    assert not (np.isfinite(X_out[1]).all(-1) & np.isfinite(X_out[2]).all(-1)).any()   # no joint in both
    assert split_persons([np.arange(5)], other, np.ones((1, 20, 17), dtype=bool), np.arange(20)[None], 5, 2.0) is None


def hidden_pair(scene, truth):
    """The scene of :data:`PAIR` where each person is half hidden, as behind others in a crowd:
    the first shows its head and right arm in frames 0-17 only, the second the rest of its
    body in frames 12-29 only (each seen in 30 % of the frames, 6 frames both). Returns the
    scene and the true person of each pose."""
    person = truth.person[scene.poses.ids - 1]
    view, kp = scene.poses.view, scene.poses.keypoints.copy()
    keep = np.ones(len(person), dtype=bool)
    for p, (first, last), shown in ((0, (0, 18), HEAD_AND_ARM), (1, (12, 30), None)):
        mine = person == p
        keep &= ~mine | (view >= first) & (view < last)
        hidden = np.isin(np.arange(17), HEAD_AND_ARM) if shown is None else ~np.isin(np.arange(17), shown)
        kp[np.ix_(mine, hidden)] = 0.0
    rows = np.flatnonzero(keep)
    return dataclasses.replace(scene, poses=dataclasses.replace(scene.poses, keypoints=kp).subset(rows)), person[rows]


def test_two_half_hidden_neighbours_grouped_as_one_come_out_as_two(pair):
    """The grouping compares poses over the keypoints they share, and these two share few: it
    can put both in one group, which per-joint RANSAC triangulates into one body (the head of
    one, the limbs of the other) whose reprojection explains every pose of both. The
    association splits it into the two people."""
    scene, person = hidden_pair(*pair)
    first = np.flatnonzero(person == 0)
    second = np.flatnonzero((person == 1) & ~np.isin(scene.poses.view, scene.poses.view[first]))
    one = [np.sort(np.concatenate([first, second]))]                   # both people, one pose per view
    config = Config(refine=False).for_driver("scene")
    triangulated = triangulate_groups(scene.cameras, scene.poses, one, config)
    groups, _ = associate_poses(scene.cameras, scene.poses, one, triangulated, config)
    assert len(groups) == 2
    precision, recall = matching_precision_recall(groups, person)
    assert precision == 1.0 and recall == 1.0
    assert sorted(map(tuple, (np.sort(g).tolist() for g in groups))) == \
        sorted(tuple(np.flatnonzero(person == p).tolist()) for p in (0, 1))     # every pose, rightly


def test_a_split_that_the_assignment_keeps_comes_back_triangulated(pair):
    """The same two people as their only poses: the split parts are what the assignment gives
    at once, and the association stops there; the triangulation it returns is that of the two
    parts (one person each), not of the group it split."""
    scene, person = hidden_pair(*pair)
    first = np.flatnonzero(person == 0)
    rows = np.sort(np.concatenate([first, np.flatnonzero((person == 1) & ~np.isin(scene.poses.view,
                                                                                     scene.poses.view[first]))]))
    scene, person = dataclasses.replace(scene, poses=scene.poses.subset(rows)), person[rows]
    config = Config(refine=False).for_driver("scene")
    one = [np.arange(len(rows))]
    triangulated = triangulate_groups(scene.cameras, scene.poses, one, config)
    groups, (obs, tri) = associate_poses(scene.cameras, scene.poses, one, triangulated, config)
    assert sorted(np.unique(person[g]).tolist() for g in groups) == [[0], [1]]
    assert len(tri.X) == len(obs.members) == 2
    for g, members in zip(groups, obs.members):
        assert sorted(members[members >= 0].tolist()) == g.tolist()
    for g, X in zip(groups, tri.X):                                  # each part's own joints
        truth = pair[1].poses3d[person[g[0]]]
        error = np.linalg.norm(X - truth, axis=-1)
        assert np.isfinite(error).sum() >= 5 and np.nanmax(error) < 0.1


def test_a_crowd_of_twenty_keeps_its_two_half_hidden_neighbours_apart():
    """20 people on a 120° arc, 150 frames: two neighbours 0.87 m apart, each behind others
    (seen in 40 and 36 frames, 10 of them both; one mostly its head, the other mostly its body),
    were one person (19 of 20, precision 0.9925)."""
    from mvm.core.reconstruct import reconstruct

    scene, truth = simulate(SimConfig.preset("realistic", people=20, frames=150, arc_deg=120, seed=2))
    person = truth.person[scene.poses.ids - 1]
    result = reconstruct(scene, Config(refine=False))
    precision, recall = matching_precision_recall(result.persons.members, person)
    assert len(result.persons) == 20
    assert precision >= 0.995 and recall >= 0.995
    assert sorted(np.bincount(person[m][person[m] >= 0]).argmax() for m in result.persons.members) == list(range(20))


def test_a_body_is_judged_without_its_stray_joints(pair):
    """A person seen whole in no view: only its arms, a shoulder 0.5 m off along its rays and a
    wrist 1.2 m off. With so few bones the shoulder sets a scale that makes the right arm look
    short; the wrist, left out before the refinement, no longer counts."""
    from mvm.core.body_parts import body_deviation, proportion_deviation

    _, truth = pair
    arms = [5, 6, 7, 8, 9, 10]
    X = np.full((1, 17, 3), np.nan)
    X[0, arms] = truth.poses3d[0, arms]
    assert body_deviation(X, 2.0)[0] == proportion_deviation(X)[0] < 0.05
    X[0, 9] += [0.0, 1.2, 0.0]
    X[0, 5] += [0.5, 0.0, 0.0]
    assert proportion_deviation(X)[0] > 0.4 > body_deviation(X, 2.0)[0]           # refused, kept


#: Joints of the person whose head and left arm a mixed body takes (with the rest of its
#: neighbour, these make a body of human proportions: no bone over 1.2 times its proportion).
HEAD_AND_LEFT_ARM = [0, 1, 2, 3, 4, 5, 7, 9]


def mixed_pair(scene, truth):
    """The scene of :data:`PAIR` where the first person shows only its head and left arm, in
    frames 0-17, and the second its body in frames 12-29, its head and left arm in every third
    of them only (each hidden behind others): the grouping of two half-hidden neighbours as one
    group (the first's poses and the second's of the other frames), the true person of each
    pose."""
    person = truth.person[scene.poses.ids - 1]
    view, kp = scene.poses.view, scene.poses.keypoints.copy()
    first = person == 0
    head = np.isin(np.arange(17), HEAD_AND_LEFT_ARM)
    kp[np.ix_(first, ~head)] = 0.0
    kp[np.ix_(~first & (view % 3 > 0), head)] = 0.0
    keep = (first & (view < 18)) | ((person == 1) & (view >= 12) & (view < 30))
    rows = np.flatnonzero(keep)
    scene = dataclasses.replace(scene, poses=dataclasses.replace(scene.poses, keypoints=kp).subset(rows))
    person, view = person[rows], view[rows]
    one = np.flatnonzero((person == 0) | (view >= 18))
    return scene, person, one


def test_neighbours_whose_mixed_body_has_human_proportions_are_split_by_their_views(pair):
    """Two people 0.45 m apart grouped as one: the head and left arm of one with the rest of the
    other make a body of human proportions (no bone says it is two), but the views of the
    second see their own head and arm 0.45 m from where the body puts them: the views split
    into two consistent halves, and the association splits the person."""
    from mvm.core.keypoints import bone_ratios

    _, truth = pair
    mixed = truth.poses3d[1].copy()
    mixed[HEAD_AND_LEFT_ARM] = truth.poses3d[0][HEAD_AND_LEFT_ARM]
    assert np.nanmax(bone_ratios(mixed[None])) < 1.2 < Config().max_bone_ratio
    scene, person, one = mixed_pair(*pair)
    config = Config(refine=False).for_driver("scene")
    triangulated = triangulate_groups(scene.cameras, scene.poses, [one], config)
    merged = triangulated[1].X[0]
    assert np.nanmax(np.linalg.norm(merged[HEAD_AND_LEFT_ARM] - truth.poses3d[0][HEAD_AND_LEFT_ARM], axis=-1)) < 0.1
    groups, (_, tri) = associate_poses(scene.cameras, scene.poses, [one], triangulated, config)
    assert sorted(np.unique(person[g]).tolist() for g in groups) == [[0], [1]]
    precision, recall = matching_precision_recall(groups, person)
    assert precision == 1.0 and recall >= 0.9
    for g, X in zip(groups, tri.X):                                  # each body is its own person's
        error = np.linalg.norm(X - truth.poses3d[person[g[0]]], axis=-1)
        assert np.isfinite(error).sum() >= 5 and np.nanmax(error) < 0.1


def test_a_real_person_whose_views_see_it_whole_is_not_split(pair):
    """One true person whose inlier views fall into two sets of joints, each set's views having
    the other's keypoints too, as inliers: its views do not contradict it, one body."""
    _, truth = pair
    _, inliers = two_bodies(truth)
    X = truth.poses3d[1][None]
    observed = np.ones_like(inliers)
    assert (body_parts(X, inliers | observed, 5, 2.0, observed) == -1).all()    # seen whole
    assert (body_parts(X, inliers, 5, 2.0, inliers) == -1).all()      # each set's views see nothing else


def test_a_joint_few_of_its_views_agree_on_is_left_out_of_the_proportions(pair):
    """A person half hidden for a whole video (the 20-person crowd over a 90° arc, 3,600 frames):
    its head, right arm, a hip and its ankles; 44 of its poses put its left shoulder 0.5 m off
    (the others hide it), while 1,029 agree on its nose. With so few bones that shoulder makes
    the body look inhuman; left out, the rest is the person's own. A body whose joints its views
    agree on alike is judged whole, and so is a cluster of a few false poses."""
    from mvm.core.body_parts import body_deviation

    _, truth = pair
    kept = [0, 1, 2, 3, 4, 5, 6, 7, 8, 10, 11, 15, 16]
    X = np.full((1, 17, 3), np.nan)
    X[0, kept] = truth.poses3d[0, kept]
    X[0, 5] += [0.0, -0.3, -0.4]                                          # 0.5 m off
    X[0, 11] += [0.05, 0.0, 0.03]
    seen = np.zeros((1, 17))
    seen[0, kept] = [984, 1029, 961, 796, 1017, 44, 810, 146, 606, 733, 29, 282, 152]
    limit = Config().association_max_proportion_deviation
    assert body_deviation(X, 2.0)[0] > limit                              # refused as it was
    assert not body_deviation(X, 2.0, seen)[0] > limit                    # kept: its shoulder left out
    even = np.where(np.isfinite(X).all(-1), 500.0, 0.0)
    assert body_deviation(X, 2.0, even)[0] == body_deviation(X, 2.0)[0]
    rng = np.random.default_rng(0)                                        # a few false poses agreeing
    cluster = truth.poses3d[0][None] + rng.normal(0.0, 1.0, (1, 17, 3))
    few = rng.integers(2, 6, (1, 17)).astype(float)                       # 2-5 views each: none left out
    assert body_deviation(cluster, 2.0, few)[0] == body_deviation(cluster, 2.0)[0]


@pytest.mark.slow
def test_the_crowd_of_twenty_over_a_90_degree_arc_is_twenty():
    """The same crowd over a 90° arc, 600 frames: two seated neighbours 0.87 m apart made one
    body of human proportions (the head and right arm of one, the rest of the other: 19 of 20,
    19.6 mm); their views contradict it, and each is found where the truth puts it."""
    from mvm.core.reconstruct import reconstruct
    from mvm.metrics.poses import MATCH_DISTANCE_M, match_persons, person_errors

    scene, truth = simulate(SimConfig.preset("realistic", people=20, frames=600, arc_deg=90, seed=2))
    person = truth.person[scene.poses.ids - 1]
    result = reconstruct(scene, Config(refine=False))
    precision, recall = matching_precision_recall(result.persons.members, person)
    assert len(result.persons) == 20 and precision >= 0.995 and recall >= 0.995
    pairs = match_persons(result.persons.keypoints3d, truth.poses3d, MATCH_DISTANCE_M)
    assert sorted(int(t) for _, t in pairs) == list(range(20))
    mpjpe, _ = person_errors(result.persons.keypoints3d, truth.poses3d, pairs)
    assert np.max(mpjpe) < 0.05                                   # the mixed body was 0.2 m off and more
