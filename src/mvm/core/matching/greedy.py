"""Algorithm 1 of the paper: greedy mutual-consistency grouping.

The pseudo-code selects the candidate with the largest *sum* of confidence-weighted
affinities to the group, ``Σ_{p∈G} w_x w_p A(x, p)``, and stops "when the confidence falls
below τ". A sum grows with the group, so comparing it with a fixed τ would accept anything
once a group is large. We keep the paper's selection rule and compare with τ its
normalization by the group's total confidence,

    ā(x) = Σ_{p∈G} w_p A(x, p) / Σ_{p∈G, D(x,p) defined} w_p,

the confidence-weighted *mean* affinity of the candidate to the members with which it can be
compared (a pair sharing too few keypoints, or two views with no baseline, has no defined
distance and neither supports nor contradicts the candidate). For a given group
the denominator is the same for every candidate, so the choice of the candidate is exactly
the paper's; the stopping test no longer depends on the group's size. A candidate must agree
with the group as a whole: a pose of a neighbour that is consistent with a few members (as
happens pairwise on a near-horizontal camera arc) has a low mean over the many others.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def greedy_groups(A: np.ndarray, score: np.ndarray, view: np.ndarray, tau: float,
                  min_score: float = 0.0, min_group_size: int = 1, release: bool = False) -> list[np.ndarray]:
    """Greedy grouping of Algorithm 1.

    Args:
        A: ``(N, N)`` symmetric affinities; NaN where the distance is undefined.
        score: ``(N,)`` pose confidences w.
        view: ``(N,)`` view of each pose; a group holds at most one pose per view.
        tau: a candidate joins while its weighted mean affinity ā to the group is >= tau.
        min_score: poses below this confidence neither seed nor join.
        min_group_size: smaller groups are dropped, their poses visited.
        release: a dropped group's poses stay available to the groups seeded after it instead
            (its seed no longer seeds): a person of four cameras whose first seed closed on two
            of them is found again from another. For the instants of a rig, whose grouping is
            final; a scene's association in 3D brings such poses back itself.
    Returns:
        groups: arrays of pose indices, in the order they were built (seeds first).

    Memory: ``A`` is only read, one row per pose (``O(N)`` extra); time ``O(N²)``.

    Four poses in three views: 0 and 2 agree with the confident seed 1, pose 3 (view 2, as pose 2)
    agrees with nothing and seeds a group of its own:

    >>> A = np.array([[np.nan, 0.4, 0.3, 0.0], [0.4, np.nan, 0.45, 0.05], [0.3, 0.45, np.nan, np.nan],
    ...               [0.0, 0.05, np.nan, np.nan]])
    >>> greedy_groups(A, np.array([0.8, 0.9, 0.7, 0.6]), np.array([0, 1, 2, 2]), tau=0.2)
    [array([1, 0, 2]), array([3])]
    >>> greedy_groups(A, np.array([0.8, 0.9, 0.7, 0.6]), np.array([0, 1, 2, 2]), tau=0.2, min_group_size=2)
    [array([1, 0, 2])]
    """
    N = len(score)
    if A.shape != (N, N) or np.shape(view) != (N,):
        raise ValueError(f"greedy_groups: expected A (N, N) and view (N,) with N = {N}, "
                         f"got {A.shape} and {np.shape(view)}")
    return greedy_groups_blocks(A[None], np.asarray(score)[None], np.asarray(view)[None], tau, min_score,
                                min_group_size, release)[0]


def _one_block(A: np.ndarray, w: np.ndarray, view: np.ndarray, eligible: np.ndarray, tau: float,
               min_group_size: int, release: bool) -> list[np.ndarray]:
    """The steps of :func:`greedy_groups_blocks` for a single block (a scene), on ``(n,)`` state
    and scalars: the same choices and the same sums, without the per-step gathers of the
    batched version, whose fixed cost dominates on a few dozen poses. ``A: (n, n)``; ``w, view,
    eligible: (n,)``, ``n >= 1``."""
    n = len(w)
    available = eligible.copy()
    seedable = eligible.copy()
    groups: list[np.ndarray] = []
    while True:
        seed = int(np.argmax(np.where(available & seedable, w, -np.inf)))
        if not (available[seed] and seedable[seed]):
            return groups
        members = [seed]
        open_ = available.copy()
        weighted_sum = np.zeros(n)
        total_weight = np.zeros(n)
        x = seed
        while True:
            available[x] = False
            open_ &= view != view[x]
            a = np.asarray(A[x], dtype=np.float32)
            defined = ~np.isnan(a)
            weight = w[x:x + 1]                                               # float64, as the blocks'
            weighted_sum += weight * np.where(defined, a, np.float32(0))          # Σ_p w_p A(x, p)
            total_weight += weight * defined                                      # Σ_p w_p [A defined]
            x = int(np.argmax(np.where(open_, w * weighted_sum, -np.inf)))
            total = total_weight[x]
            if not (open_[x] and weighted_sum[x] >= tau * total and total != 0):
                break
            members.append(x)
        if len(members) >= min_group_size:
            groups.append(np.array(members, dtype=np.intp))
        elif release:                                # too small: its poses stay for later groups
            available[members] = True
            seedable[seed] = False


def greedy_groups_blocks(A: np.ndarray, score: np.ndarray, view: np.ndarray, tau: float,
                         min_score: float = 0.0, min_group_size: int = 1,
                         release: bool = False) -> list[list[np.ndarray]]:
    """:func:`greedy_groups` in ``B`` independent blocks at once (the instants of a rig), all
    blocks advancing in step: one vectorized step seeds or grows one group in every block.

    ``A: (B, n, n)``, ``score: (B, n)``, ``view: (B, n)`` (-1: padding, never grouped) -> for
    each block its groups (indices into the block), in the order they were built.
    """
    B, n = np.shape(view)
    if n == 0:
        return [[] for _ in range(B)]
    w = np.asarray(score, dtype=float)
    w = np.where(np.isfinite(w), w, 0.0)
    if B == 1:
        view = np.asarray(view)
        return [_one_block(A[0], w[0], view[0], (view[0] >= 0) & (w[0] >= min_score), tau, min_group_size,
                           release)]
    state = _Growth(eligible=(view >= 0) & (w >= min_score), joined=np.full((B, n), -1), seed=np.zeros((B, n), bool),
                    weighted_sum=np.zeros((B, n)), total_weight=np.zeros((B, n)), open_=np.zeros((B, n), bool),
                    growing=np.zeros(B, bool), done=np.zeros(B, bool), tried=np.zeros((B, n), bool),
                    start=np.zeros(B, np.int64))
    step, closed = 0, True
    while True:
        if closed:
            _seed(A, w, view, state, step)
            if not state.growing.any():
                break
        closed = _grow(A, w, view, state, tau, step, min_group_size if release else 1)
        step += 1
    return _collect(state.joined, state.seed, min_group_size)


@dataclass
class _Growth:
    """The state of :func:`greedy_groups_blocks`, ``(B, n)`` per pose or ``(B,)`` per block:
    the step at which each pose ``joined`` a group (-1: not yet; a pose that joined is no longer
    available) and whether it was the group's ``seed``; the weighted sum and total weight of
    affinities of each candidate to the growing group; ``open_`` candidates; the poses that
    ``tried`` as seeds of a group too small (they may still join another); the step at which
    each block's current group started."""

    eligible: np.ndarray
    joined: np.ndarray
    seed: np.ndarray
    weighted_sum: np.ndarray
    total_weight: np.ndarray
    open_: np.ndarray
    growing: np.ndarray
    done: np.ndarray
    tried: np.ndarray
    start: np.ndarray


def _affinity_rows(A: np.ndarray, b: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Affinities of pose ``x`` of block ``b`` (``(k,)`` each) to its block (undefined -> 0)
    and where they are defined, ``(k, n)`` each. Each pose's row is read once (as seed or as
    member): no ``n × n`` temporary."""
    a = np.asarray(A[b, x], dtype=np.float32)
    defined = a == a
    return np.where(defined, a, np.float32(0)), defined


def _join(A: np.ndarray, w: np.ndarray, view: np.ndarray, s: _Growth, b: np.ndarray, x: np.ndarray,
          step: int, rows: np.ndarray | slice | None = None) -> None:
    """Pose ``x`` of block ``b`` joins the block's current group; ``rows``: ``b`` as an index
    of rows (``slice(None)`` when ``b`` is every block, to update in place)."""
    rows = b if rows is None else rows
    s.joined[b, x] = step
    s.open_[rows] &= view[rows] != view[b, x][:, None]
    a, defined = _affinity_rows(A, b, x)
    weight = w[b, x][:, None]
    s.weighted_sum[rows] += weight * a                                        # Σ_p w_p A(x, p)
    s.total_weight[rows] += weight * defined                                  # Σ_p w_p [A defined]


def _seed(A: np.ndarray, w: np.ndarray, view: np.ndarray, s: _Growth, step: int) -> None:
    """Every block without a growing group starts one from its most confident available pose
    (the first in index order among equals), or is done."""
    b = np.flatnonzero(~s.growing & ~s.done)
    if not len(b):
        return
    available = s.eligible[b] & (s.joined[b] < 0)
    seed = np.argmax(np.where(available & ~s.tried[b], w[b], -np.inf), axis=1)
    found = (available & ~s.tried[b])[np.arange(len(b)), seed]
    s.done[b[~found]] = True
    b, seed, available = b[found], seed[found], available[found]
    s.seed[b, seed] = True
    s.start[b] = step
    s.weighted_sum[b] = 0.0
    s.total_weight[b] = 0.0
    s.open_[b] = available
    _join(A, w, view, s, b, seed, step)
    s.growing[b] = True


def _grow(A: np.ndarray, w: np.ndarray, view: np.ndarray, s: _Growth, tau: float, step: int,
          min_group_size: int = 1) -> bool:
    """Every growing group takes the open candidate with the largest weighted sum of affinities
    (the paper's rule) while its weighted mean affinity ā is >= ``tau``; otherwise it closes, and
    a group of fewer than ``min_group_size`` poses gives them back (:func:`_release`).
    Returns whether a group closed."""
    b = np.flatnonzero(s.growing)
    every = len(b) == len(w)                                      # no gathers needed
    open_, weighted_sum = (s.open_, s.weighted_sum) if every else (s.open_[b], s.weighted_sum[b])
    gain = np.where(open_, (w if every else w[b]) * weighted_sum, -np.inf)
    best = np.argmax(gain, axis=1)
    k = np.arange(len(b))
    total = s.total_weight[b, best]
    accept = open_[k, best] & (weighted_sum[k, best] >= tau * total) & (total != 0)
    if accept.all():
        _join(A, w, view, s, b, best, step + 1, slice(None) if every else b)
        return False
    _join(A, w, view, s, b[accept], best[accept], step + 1)
    s.growing[b[~accept]] = False
    if min_group_size > 1:
        _release(s, b[~accept], min_group_size)
    return True


def _release(s: _Growth, b: np.ndarray, min_group_size: int) -> None:
    """The groups that just closed in blocks ``b`` with fewer than ``min_group_size`` poses give
    their poses back to later groups; their seeds no longer seed (``tried``)."""
    members = s.joined[b] >= s.start[b][:, None]                               # (k, n) the closed group
    small = members.sum(1) < min_group_size
    if not small.any():
        return
    b, members = b[small], members[small]
    s.tried[b] |= members & s.seed[b]
    s.seed[b] &= ~members
    s.joined[b] = np.where(members, -1, s.joined[b])


def _collect(joined: np.ndarray, seed: np.ndarray, min_group_size: int) -> list[list[np.ndarray]]:
    """Per block, its groups in the order they were built, each's members in the order they
    joined (``joined: (B, n)`` steps; a ``seed: (B, n)`` starts a group)."""
    out: list[list[np.ndarray]] = [[] for _ in range(len(joined))]
    b, x = np.nonzero(joined >= 0)
    order = np.lexsort((joined[b, x], b))
    b, x = b[order], x[order]
    for members in np.split(np.stack([b, x]), np.flatnonzero(seed[b, x])[1:], axis=1):
        if members.shape[1] >= min_group_size:
            out[members[0, 0]].append(members[1])
    return out
