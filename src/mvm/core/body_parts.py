"""Two people triangulated as one: the parts of a person that no pose links.

In a crowd, a person behind others is seen whole in no view: one shows only its head, the next
its head and an elbow. Two such neighbours, each seen in a few views and mostly not in the same
ones, can have poses whose keypoints are other joints (one's head, the other's body): those
poses share too few keypoints to be compared (the epipolar affinity of the grouping, the
reprojection distance of the association, both over the joints two observations have in
common), so nothing keeps them apart. Triangulated joint by joint, such a group gives a body
whose head is one person's and whose limbs are the other's, and whose reprojection explains
the poses of both.

What gives it away is that no pose sees both parts: within one person, the joints a pose is an
inlier of are *linked*, and the links of a real person join its joints into one body, while
the links of two people make two parts, joined only by bones of no human proportion (a forearm
from one person's elbow to the other's wrist). :func:`body_parts` finds such persons;
:func:`split_members` divides their poses between the parts.

Arrays: ``P`` persons, ``M`` view slots of each (its group's poses), ``J = 17`` joints. Pure numpy.
"""
from __future__ import annotations

import numpy as np

from mvm.core.keypoints import BONES, bone_ratios

#: Two joints of a person are linked when at least this share of the inlier views of the less
#: seen of them has both as inliers (a stray keypoint of a crowded view links nothing). [0-1]
LINK_SHARE = 0.1


def linked_parts(inliers: np.ndarray, reconstructed: np.ndarray) -> np.ndarray:
    """Connected parts of each person's joints under the links of :data:`LINK_SHARE`.

    ``inliers: (P, M, J)`` bool, each view slot's inlier keypoints; ``reconstructed: (P, J)``
    bool. Returns ``(P, J)`` int, the part of each joint, named by its lowest joint index
    (-1: not reconstructed). Cost ``P · M · J²``: linear in the views.

    >>> inl = np.zeros((1, 4, 17), dtype=bool); inl[0, :2, :8] = True; inl[0, 2:, 8:] = True
    >>> linked_parts(inl, np.ones((1, 17), dtype=bool))[0].tolist()
    [0, 0, 0, 0, 0, 0, 0, 0, 8, 8, 8, 8, 8, 8, 8, 8, 8]
    """
    used = (inliers & reconstructed[:, None, :]).astype(np.float32)       # (P, M, J)
    shared = used.transpose(0, 2, 1) @ used                                 # (P, J, J) views seeing both
    seen = np.diagonal(shared, axis1=1, axis2=2)                            # (P, J)
    fewer = np.minimum(seen[:, :, None], seen[:, None, :])
    reach = (shared > 0) & (shared >= LINK_SHARE * fewer)
    reach |= np.eye(shared.shape[-1], dtype=bool) & reconstructed[:, :, None]
    for _ in range(int(np.ceil(np.log2(max(shared.shape[-1], 2))))):     # transitive closure by squaring
        r = reach.astype(np.float32)
        reach = r @ r > 0
    first = np.argmax(reach, axis=-1)                                       # lowest joint each reaches
    return np.where(reconstructed, first, -1)


def body_parts(X: np.ndarray, inliers: np.ndarray, min_joints: int, max_bone_ratio: float) -> np.ndarray:
    """The persons that are two people: two parts of at least ``min_joints`` joints each that no
    pose links (:func:`linked_parts`), joined by a bone longer than ``max_bone_ratio`` times its
    proportion at the person's scale (:func:`mvm.core.keypoints.bone_ratios`; a real person seen
    in two disjoint sets of views has its parts at human proportions).

    ``X: (P, J, 3)`` (NaN: not reconstructed), ``inliers: (P, M, J)``. Returns ``(P, J)`` int:
    0 for the joints of the larger part, 1 for the other's, -1 elsewhere (joints of neither,
    and every joint of a person that is one body).

    >>> X = np.zeros((1, 17, 3)); X[0, :, 0] = np.arange(17) * 0.1; X[0, 9:, 2] = 2.0
    >>> inl = np.zeros((1, 4, 17), dtype=bool); inl[0, :2, :9] = True; inl[0, 2:, 9:] = True
    >>> body_parts(X, inl, 5, 2.0)[0].tolist()
    [0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1]
    """
    reconstructed = np.isfinite(X).all(-1)
    part = linked_parts(inliers, reconstructed)                              # (P, J)
    J = X.shape[1]
    size = (part[:, :, None] == np.arange(J)).sum(1)                          # (P, J) joints of each part
    order = np.argsort(-size, axis=1, kind="stable")
    first, second = order[:, 0], order[:, 1]
    p = np.arange(len(X))
    two = size[p, second] >= min_joints
    label = np.where(part == first[:, None], 0, np.where(part == second[:, None], 1, -1))
    ends = np.array(BONES)
    a, b = label[:, ends[:, 0]], label[:, ends[:, 1]]                         # (P, B)
    with np.errstate(invalid="ignore"):
        across = (a >= 0) & (b >= 0) & (a != b) & (bone_ratios(X) > max_bone_ratio)
    two &= across.any(1)
    return np.where(two[:, None], label, -1)


def split_members(members: np.ndarray, inliers: np.ndarray, label: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pose of a person of two parts to the part it has more inlier joints in (ties, and
    poses of no inlier: the larger part). ``members: (P, M)`` pose index of each slot (-1:
    padding), ``inliers: (P, M, J)``, ``label: (P, J)`` from :func:`body_parts`. Returns the
    ``(K,)`` poses of the parts ``1`` and the ``(K,)`` person each came from; the others stay."""
    votes = np.stack([(inliers & (label == k)[:, None, :]).sum(-1) for k in (0, 1)])   # (2, P, M)
    second = (votes[1] > votes[0]) & (members >= 0) & (label.max(1) == 1)[:, None]
    person, slot = np.nonzero(second)
    return members[person, slot], person


def split_persons(groups: list[np.ndarray], X: np.ndarray, inliers: np.ndarray, members: np.ndarray,
                  min_joints: int, max_bone_ratio: float) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, np.ndarray] | None:
    """The persons of :func:`body_parts` split in two, or None where every person is one body.

    ``groups``: the ``P`` groups of pose indices triangulated as ``X: (P, J, 3)``, with
    ``inliers: (P, M, J)`` and ``members: (P, M)`` (their slots' poses, -1: padding). Each part
    follows its person (scenes stay in order) with the joints of its part only (the others NaN,
    to be triangulated from its own poses), and its poses (:func:`split_members`). Returns
    ``(groups, X, person, part)``: ``person: (P',)`` the person each new group comes from,
    ``part: (P',)`` its part (0, 1; -1: the whole person)."""
    label = body_parts(X, inliers, min_joints, max_bone_ratio)                # (P, J)
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
