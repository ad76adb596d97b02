"""Two people triangulated as one, told by a bone whose ends no view sees together; and the
proportions of a body.

In a crowd, a person behind others is seen whole in no view: one shows only its head, the next
its head and an elbow. Two such neighbours, each seen in a few views and mostly not in the same
ones, can have poses whose keypoints are other joints (one's head, the other's body): those
poses share too few keypoints to be compared (the epipolar affinity of the grouping, the
reprojection distance of the association, both over the joints two observations have in
common), so nothing keeps them apart. Triangulated joint by joint, such a group gives a body
whose head is one person's and whose limbs are the other's, and whose reprojection explains
the poses of both.

What gives it away is a bone of no human proportion (a forearm from one person's elbow to the
other's wrist) whose two ends no view sees together: in a view of one person, both ends of
its bones are inliers, or one of them is hidden and the other is not an inlier either.
:func:`body_parts` finds such persons and the joints of each of the two people;
:func:`split_members` divides their poses between them, :func:`split_persons` their groups.

Arrays: ``P`` persons, ``M`` view slots of each (its group's poses), ``J = 17`` joints. Pure numpy.
"""
from __future__ import annotations

import numpy as np

from mvm.core.keypoints import BONES, bone_ratios, stray_joints
from mvm.core.quality import row_nanmedian

#: The two ends of a bone are seen apart when fewer than this share of the inlier views of the
#: less seen end have both as inliers (the views of one person see both ends of its bones, or
#: one of them hidden: then the other is not an inlier of that view either). [0-1]
LINK_SHARE = 0.1


def shared_views(inliers: np.ndarray, reconstructed: np.ndarray) -> np.ndarray:
    """``(P, J, J)`` float: the views in which both joints are inliers, for each person (the
    diagonal: each joint's inlier views). ``inliers: (P, M, J)`` bool, ``reconstructed: (P, J)``
    bool. Cost ``P · M · J²``: linear in the views.

    >>> inliers = np.array([[[True, True], [True, False], [False, False]]])      # 1 person, 3 views, 2 joints
    >>> shared_views(inliers, np.array([[True, True]]))
    array([[[2., 1.],
            [1., 1.]]], dtype=float32)
    """
    used = (inliers & reconstructed[:, None, :]).astype(np.float32)       # (P, M, J)
    return used.transpose(0, 2, 1) @ used


def body_parts(X: np.ndarray, inliers: np.ndarray, min_joints: int, max_bone_ratio: float,
               observed: np.ndarray | None = None) -> np.ndarray:
    """The persons that are two people, and the joints of each.

    A person is two people when one of its bones has two ends seen apart (:data:`LINK_SHARE`):
    each end is another person's joint. The longest such bone names the two people (one
    longer than ``max_bone_ratio`` times its proportion at the person's scale,
    :func:`mvm.core.keypoints.bone_ratios`, first); a joint goes to the end it is seen with,
    not apart from, and to neither where it is seen with both (a joint triangulated from both
    people's keypoints, or a real person's joint: the body of one person is seen with both ends
    of any bone) or with none. Both people need ``min_joints`` joints, and the two sets of
    joints are seen apart too (fewer than :data:`LINK_SHARE` of the views of the less seen one
    see both): a real person's sides, each seen from its end of the arc, are seen together from
    the middle, and a stray joint, seen apart from its neighbour, is seen with the rest of its
    body. Then it is two people when the bone is over ``max_bone_ratio``, or when the views of
    one set contradict the other (:func:`contradicted`, with ``observed``): two neighbours
    whose mixed body has human proportions, the views of one seeing the other's joints
    elsewhere.

    ``X: (P, J, 3)`` (NaN: not reconstructed), ``inliers: (P, M, J)``, ``observed: (P, M, J)``
    the keypoints each view has (None: the bone's length alone). Returns ``(P, J)`` int: 0 for
    the joints of the person at the bone's first end, 1 for the other's, -1 elsewhere (and for
    every joint of a person that is one body).

    >>> X = np.zeros((1, 17, 3)); X[0, :, 0] = np.arange(17) * 0.1; X[0, 9:, 2] = 2.0
    >>> inl = np.zeros((1, 4, 17), dtype=bool); inl[0, :2, :9] = True; inl[0, 2:, 9:] = True
    >>> body_parts(X, inl, 5, 2.0)[0].tolist()
    [0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1]
    """
    reconstructed = np.isfinite(X).all(-1)
    shared = shared_views(inliers, reconstructed)                            # (P, J, J)
    seen = np.diagonal(shared, axis1=1, axis2=2)                            # (P, J)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = shared / np.minimum(seen[:, :, None], seen[:, None, :])      # NaN: a joint unseen
        ratio = bone_ratios(X)                                              # (P, B)
        long = ratio > max_bone_ratio
    ends = np.array(BONES)
    p = np.arange(len(X))
    apart = share[:, ends[:, 0], ends[:, 1]] < LINK_SHARE                    # (P, B)
    if observed is None:
        apart &= long
    rank = np.where(apart, np.where(long, ratio, 0.0) + np.nan_to_num(ratio) * 1e-3, -np.inf)
    bone = np.argmax(rank, axis=1)                                           # (P,) the longest
    a, b = ends[bone, 0], ends[bone, 1]
    to_a, to_b = share[p, :, a] >= LINK_SHARE, share[p, :, b] >= LINK_SHARE  # (P, J)
    label = np.where(to_a & ~to_b, 0, np.where(to_b & ~to_a, 1, -1))
    two = apart[p, bone] & ((label == 0).sum(1) >= min_joints) & ((label == 1).sum(1) >= min_joints)
    views = [(inliers & (label == k)[:, None, :]).any(-1) for k in (0, 1)]     # (P, M) each
    both = (views[0] & views[1]).sum(1)
    two &= both < LINK_SHARE * np.minimum(views[0].sum(1), views[1].sum(1))
    if observed is not None:
        two &= long[p, bone] | contradicted(inliers, observed, label, views, min_joints)
    return np.where(two[:, None], label, -1)


#: The views of one part contradict the other part when at least this share of the other
#: part's keypoints they have are no inliers. [0-1]
CONTRADICTION = 0.5


def contradicted(inliers: np.ndarray, observed: np.ndarray, label: np.ndarray, views: list[np.ndarray],
                 min_keypoints: int) -> np.ndarray:
    """``(P,)`` bool: the persons one of whose two parts is seen elsewhere by the views of the
    other: of the keypoints of part ``1 - k`` that the views of part ``k`` have (at least
    ``min_keypoints``), :data:`CONTRADICTION` or more are no inliers. The views of one person
    see its own joints where its triangulation puts them; those of a neighbour whose joints a
    mixed body took see them 0.45 m and more away. Both parts need ``min_keypoints`` views of
    their own (each half a person that its views alone triangulate, not a stray detection).

    ``inliers, observed: (P, M, J)`` bool, ``label: (P, J)`` part of each joint (-1: neither),
    ``views``: the ``(P, M)`` views of parts 0 and 1."""
    out = np.zeros(len(label), dtype=bool)
    halves = (views[0].sum(1) >= min_keypoints) & (views[1].sum(1) >= min_keypoints)
    for k in (0, 1):
        had = observed & views[k][..., None] & (label == 1 - k)[:, None, :]   # (P, M, J)
        count, missed = had.sum((1, 2)), (had & ~inliers).sum((1, 2))
        out |= (count >= min_keypoints) & (missed >= CONTRADICTION * count)
    return out & halves


def split_members(members: np.ndarray, inliers: np.ndarray, label: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pose of a person of two parts to the part it has more inlier joints in (ties, and
    poses of no inlier in either: part 0). ``members: (P, M)`` pose index of each slot (-1:
    padding), ``inliers: (P, M, J)``, ``label: (P, J)`` from :func:`body_parts`. Returns the
    ``(K,)`` poses of the parts ``1`` and the ``(K,)`` person each came from; the others stay."""
    votes = np.stack([(inliers & (label == k)[:, None, :]).sum(-1) for k in (0, 1)])   # (2, P, M)
    second = (votes[1] > votes[0]) & (members >= 0) & (label.max(1) == 1)[:, None]
    person, slot = np.nonzero(second)
    return members[person, slot], person


def split_persons(groups: list[np.ndarray], X: np.ndarray, inliers: np.ndarray, members: np.ndarray,
                  min_joints: int, max_bone_ratio: float, observed: np.ndarray | None = None,
                  ) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, np.ndarray] | None:
    """The persons of :func:`body_parts` split in two, or None where every person is one body.

    ``groups``: the ``P`` groups of pose indices triangulated as ``X: (P, J, 3)``, with
    ``inliers, observed: (P, M, J)`` and ``members: (P, M)`` (their slots' poses, -1: padding). Each part
    follows its person (scenes stay in order) with the joints of its part only (the others NaN,
    to be triangulated from its own poses), and its poses (:func:`split_members`). Returns
    ``(groups, X, person, part)``: ``person: (P',)`` the person each new group comes from,
    ``part: (P',)`` its part (0, 1; -1: the whole person)."""
    label = body_parts(X, inliers, min_joints, max_bone_ratio, observed)      # (P, J)
    split = np.flatnonzero(label.max(1) == 1)
    if not len(split):
        return None
    moved, origin = split_members(members, inliers, label)
    out_groups: list[np.ndarray] = []
    rows: list[tuple[int, int]] = []                                          # (person, part: -1 whole)
    for q, g in enumerate(groups):
        if label[q].max() < 1:
            out_groups.append(g)
            rows.append((q, -1))
            continue
        second = moved[origin == q]
        out_groups += [np.setdiff1d(g, second), np.sort(second)]
        rows += [(q, 0), (q, 1)]
    person, part = (np.array(c) for c in zip(*rows))
    keep = (part[:, None] < 0) | (label[person] == part[:, None])             # (P', J) joints kept
    return out_groups, np.where(keep[..., None], X[person], np.nan), person, part


def proportion_deviation(X: np.ndarray, min_bones: int = 4) -> np.ndarray:
    """How far each person's bone lengths are from human proportions, whatever the posture
    and the model's scale: the median over bones of ``|l / (s · l_mean) - 1|`` with ``s`` the
    median of ``l / l_mean``. About 0.05 for a real person; a cluster of false positives that
    happens to triangulate gives 0.5 and more.

    ``X: (Q, J, 3)`` -> ``(Q,)``, NaN where fewer than ``min_bones`` bones are reconstructed.

    >>> proportion_deviation(np.full((1, 17, 3), np.nan)).tolist()
    [nan]
    """
    ratio = bone_ratios(X)
    deviation = row_nanmedian(np.abs(ratio - 1))
    return np.where(np.isfinite(ratio).sum(1) >= min_bones, deviation, np.nan)


#: A joint is left out of a body's proportions when fewer than this share of the inlier views of
#: the person's best seen joint agree on it. [0-1]
WEAK_JOINT_SHARE = 0.1


def body_deviation(X: np.ndarray, max_bone_ratio: float, seen: np.ndarray | None = None) -> np.ndarray:
    """:func:`proportion_deviation` of the bodies the reconstruction keeps, those without the
    joints :func:`mvm.core.keypoints.stray_joints` leaves out (bones over ``max_bone_ratio``; 0:
    none left out), where that is lower than with them (NaN, fewer than 4 bones left: with them).
    A person seen whole in no view may have a joint seen from one side of the arc only, far along
    its rays, and with few bones the scale that joint sets makes the others look wrong too.
    With ``seen: (Q, J)``, the inlier views of each joint, the joints fewer than
    :data:`WEAK_JOINT_SHARE` of those of the person's best seen joint agree on are left out first
    (a shoulder that 44 of a person's 1,244 poses put 0.6 m off, the others hiding it, while
    1,029 agree on its nose; NaN where too few bones are left: its proportions are not judged).
    ``X: (Q, J, 3)`` -> ``(Q,)``.

    >>> X = np.full((1, 17, 3), np.nan); X[0, 5:11] = 0.0; X[0, 5:11, 0] = np.arange(5, 11) * 0.1
    >>> X[0, 10] = [0.0, 5.0, 0.0]                                  # the arms only, a wrist far off
    >>> [round(float(d[0]), 2) for d in (proportion_deviation(X), body_deviation(X, 2.0))]
    [0.16, 0.08]
    """
    if seen is not None:
        weak = seen < WEAK_JOINT_SHARE * seen.max(-1, initial=0)[:, None]        # (Q, J)
        X = np.where(weak[..., None], np.nan, X)
    whole = proportion_deviation(X)
    if max_bone_ratio <= 0 or not len(X):
        return whole
    with np.errstate(invalid="ignore"):
        kept = np.where(stray_joints(X, max_bone_ratio)[..., None], np.nan, X)
    return np.fmin(proportion_deviation(kept), whole)
