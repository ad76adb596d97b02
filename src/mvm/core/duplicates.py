"""Duplicate persons: two groups of one block (a scene, or a rig instant) whose triangulated
joints lie closer than ``merge_distance`` of the persons' size are one person seen twice (the
paper's grouping leaves such pairs where a pose of one frame fits two groups). Arrays in,
arrays out, no I/O; the pairs are tested in bounded chunks, never all at once."""
from __future__ import annotations

import numpy as np

from mvm.core.config import Config
from mvm.core.quality import row_nanquantile
from mvm.core.scene import Poses2D

#: The quantile of the joint distances :func:`duplicate_pairs` compares where a merge is final
#: (the paper's grouping): the upper quartile, so that a group mixing two people, half its
#: joints on each, is taken for neither.
FINAL_QUANTILE = 0.75
#: The same within the association in 3D, which releases the poses a merged person does not
#: explain: the median, so that a copy of a person triangulated from few views, a few of its
#: joints far off, joins it.
ASSOCIATION_QUANTILE = 0.5


def duplicate_pairs(X: np.ndarray, block: np.ndarray, max_relative_distance: float,
                    quantile: float = FINAL_QUANTILE) -> np.ndarray:
    """``(P, P)`` bool: the pairs of persons of one block whose triangulated poses coincide.

    Two persons are duplicates when the ``quantile`` of their joint distances, over the joints
    both have (a quantile, not the mean: a stray joint does not keep copies of one person
    apart), is below ``max_relative_distance`` times the larger torso length (hip to shoulder),
    which keeps the test free of the model's unknown scale; also when one is the mirror of the other
    (left and right exchanged: a group of left-right swapped detections). ``X: (P, J, 3)``,
    ``block: (P,)``; only pairs within a block are compared.

    Memory: the ``(P, P)`` result, and the pairs compared :data:`DUPLICATE_PAIRS_CHUNK` at a time
    (a block of thousands of persons has millions of pairs, each ``2 J 3`` differences).
    """
    from mvm.core.keypoints import FLIP_PERMUTATION, LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER

    P = len(X)
    close = np.zeros((P, P), dtype=bool)
    with np.errstate(invalid="ignore", divide="ignore"):                    # all-NaN rows: NaN
        bones = X[:, [LEFT_SHOULDER, RIGHT_SHOULDER]] - X[:, [LEFT_HIP, RIGHT_HIP]]
        torso = _nanmean(np.sqrt((bones * bones).sum(-1)).T, axis=0)          # (P,)
        for i, j in block_pairs(np.asarray(block), DUPLICATE_PAIRS_CHUNK):
            diff = X[i][None] - np.stack([X[j], X[j][:, FLIP_PERMUTATION]])   # as is, mirrored: (2, K, J, 3)
            apart = row_nanquantile(np.sqrt((diff * diff).sum(-1)), quantile)            # (2, K)
            close[i, j] = np.fmin(apart[0], apart[1]) < max_relative_distance * np.fmax(torso[i], torso[j])
    return close


#: Pairs of persons :func:`duplicate_pairs` compares at once: about 3 kB of working memory each.
DUPLICATE_PAIRS_CHUNK = 2**14


def block_pairs(block: np.ndarray, max_pairs: int):
    """Yield ``(i, j)``: every ordered pair of different persons of the same block (``block: (P,)``),
    in chunks of about ``max_pairs`` pairs (a person's pairs are never split)."""
    order = np.argsort(block, kind="stable")
    _, start, count = np.unique(block[order], return_index=True, return_counts=True)
    first = np.repeat(start, count)                                         # (P,) in sorted order
    length = np.repeat(count, count)
    ends = np.cumsum(length)
    if not len(ends):
        return
    cuts = np.unique(np.searchsorted(ends, np.arange(max_pairs, ends[-1], max_pairs), side="right"))
    for rows in np.split(np.arange(len(order)), cuts):
        if not len(rows):
            continue
        n = length[rows]
        offset = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        i = np.repeat(order[rows], n)
        j = order[np.repeat(first[rows], n) + offset]
        keep = i != j
        yield i[keep], j[keep]


def _nanmean(a: np.ndarray, axis: int) -> np.ndarray:
    """``np.nanmean(a, axis)``, the same numbers (NaN where a slice has none), without its
    warning machinery."""
    missing = np.isnan(a)
    return np.where(missing, 0.0, a).sum(axis) / (~missing).sum(axis)


def merge_duplicates(X: np.ndarray, groups: list[np.ndarray], view: np.ndarray,
                     max_relative_distance: float, close: np.ndarray | None = None) -> list[np.ndarray] | None:
    """Merge groups whose triangulated poses coincide (a person split into two groups), as
    :func:`duplicate_pairs` finds them (``close: (P, P)`` when already computed).

    The smaller group's poses join the larger one, except those from views the larger group
    already has; triangulation then treats a swapped keypoint as any other outlier.

    ``X: (P, J, 3)``; ``groups``: pose indices; ``view: (N,)``. Returns the new groups, or None
    when nothing merges.
    """
    P = len(groups)
    if close is None:
        close = duplicate_pairs(X, np.zeros(P, dtype=int), max_relative_distance) if P >= 2 else None
    if close is None or not close.any():
        return None
    order = np.argsort([-len(g) for g in groups], kind="stable")
    absorbed = np.zeros(P, dtype=bool)
    merged = {int(p): list(groups[p]) for p in range(P)}
    for p in order:
        if absorbed[p]:
            continue
        for q in order:
            if q == p or absorbed[q] or not close[p, q] or len(groups[q]) > len(merged[p]):
                continue
            views = set(view[merged[p]].tolist())
            merged[p] += [m for m in groups[q] if view[m] not in views]
            absorbed[q] = True
    return [np.array(merged[p]) for p in range(P) if not absorbed[p]]


def pose_groups(groups: list[np.ndarray], n: int) -> np.ndarray:
    """``(n,)`` the group (index into ``groups``, each of pose indices) each of ``n`` poses is
    in, -1 for none.

    >>> pose_groups([np.array([3, 0]), np.array([], dtype=int), np.array([2])], 5).tolist()
    [0, -1, 2, 0, -1]
    """
    owner = np.full(n, -1)
    if groups:
        owner[np.concatenate(groups).astype(np.int64)] = np.repeat(np.arange(len(groups)), [len(g) for g in groups])
    return owner


def group_blocks(poses: Poses2D, groups: list[np.ndarray]) -> np.ndarray:
    """``(P,)`` block (instant) of each group, 0 for every group of a scene."""
    if poses.instant is None or not groups:
        return np.zeros(len(groups), dtype=np.int64)
    return poses.instant[[g[0] for g in groups]]


def merge_groups(X: np.ndarray, groups: list[np.ndarray], poses: Poses2D,
                 config: Config, quantile: float = FINAL_QUANTILE) -> list[np.ndarray] | None:
    """:func:`merge_duplicates` within each block (groups come block by block, as from
    :func:`match`), the duplicates of every block found at once (:func:`duplicate_pairs` at
    ``quantile``). ``X: (P, J, 3)``. Returns the new groups, or None when nothing merges."""
    if config.merge_distance <= 0 or len(groups) < 2:
        return None
    block = group_blocks(poses, groups)
    close = duplicate_pairs(X, block, config.merge_distance, quantile)
    if not close.any():
        return None
    out: list[np.ndarray] = []
    bounds = np.flatnonzero(np.diff(block)) + 1
    for rows in np.split(np.arange(len(groups)), bounds):
        part = [groups[i] for i in rows]
        if close[rows[0]:rows[-1] + 1].any():
            part = merge_duplicates(X[rows], part, poses.view, config.merge_distance,
                                    close[rows[0]:rows[-1] + 1, rows[0]:rows[-1] + 1]) or part
        out += part
    return out


def absorb_explained(groups: list[np.ndarray], pose: np.ndarray, person: np.ndarray, cost: np.ndarray,
                     slot: np.ndarray, gate: float) -> list[np.ndarray] | None:
    """Persons seen twice that their 3D poses do not show: a person triangulated from a few
    poorly spread views can lie tenths of a metre from the person it duplicates (and fits its
    own poses better than anyone, so the assignment keeps them), yet the larger person's
    reprojection explains every one of its poses, in views the larger person has no pose in.
    Such a person joins the larger one.

    ``groups``: the pose indices of each person (the assignment's); ``pose, person, cost: (K,)``
    candidate pairs and their costs (person sizes), ``slot: (N,)`` the view (and scene) of
    every pose, ``gate``: the largest cost of an assignment. Each person is absorbed by the
    larger person that explains all its poses at the least summed cost, provided it has no pose
    in any of their views; chains are followed from the smallest. Returns the new groups, one
    per person as given (an absorbed person's empty), or None when no person is absorbed.

    >>> groups = [np.array([0, 1, 2, 3]), np.array([4, 5])]    # poses 4, 5 in views 4, 5
    >>> pose, person = np.array([4, 5, 4, 5]), np.array([0, 0, 1, 1])
    >>> [g.tolist() for g in absorb_explained(groups, pose, person, np.array([0.05, 0.04, 0.0, 0.0]),
    ...                                       np.arange(6), 0.15)]
    [[0, 1, 2, 3, 4, 5], []]
    >>> groups = [np.array([0, 1, 2, 3]), np.array([4, 5]), np.array([6])]     # 6 into 4, 5 into 0-3
    >>> [g.tolist() for g in absorb_explained(groups, np.array([6, 4, 5]), np.array([1, 0, 0]),
    ...                                       np.full(3, 0.05), np.arange(7), 0.15)]
    [[0, 1, 2, 3, 4, 5, 6], [], []]
    """
    Q = len(groups)
    if Q < 2:
        return None
    size = np.array([len(g) for g in groups])
    q = pose_groups(groups, len(slot))[pose]
    fit = (cost < gate) & (q >= 0) & (q != person)
    fit[fit] = size[person[fit]] > size[q[fit]]                      # into a larger person only
    q, r, c = q[fit], person[fit], cost[fit]
    key, inverse, count = np.unique(q * Q + r, return_inverse=True, return_counts=True)
    whole = count == size[key // Q]                                  # every pose of q explained by r
    if not whole.any():
        return None
    total = np.bincount(inverse, weights=c)[whole]
    key = key[whole][np.lexsort((total, size[key[whole] // Q]))]     # smallest person, then least cost
    views = [set(slot[g].tolist()) for g in groups]
    into = np.arange(Q)
    for q, r in zip((key // Q).tolist(), (key % Q).tolist()):
        if into[q] != q or into[r] != r or views[q] & views[r]:
            continue
        into[q] = r
        views[r] |= views[q]
    if (into == np.arange(Q)).all():
        return None
    while (into[into] != into).any():                                # a chain: into the person it ends in
        into = into[into]
    merged = [[g] for g in groups]
    for q in np.flatnonzero(into != np.arange(Q)):
        merged[into[q]].append(groups[q])
    return [np.sort(np.concatenate(merged[r])) if into[r] == r else groups[r][:0] for r in range(Q)]
