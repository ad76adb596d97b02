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

import numpy as np


def greedy_groups(A: np.ndarray, score: np.ndarray, view: np.ndarray, tau: float,
                  min_score: float = 0.0, min_group_size: int = 1) -> list[np.ndarray]:
    """Greedy grouping of Algorithm 1.

    Args:
        A: ``(N, N)`` symmetric affinities; NaN where the distance is undefined.
        score: ``(N,)`` pose confidences w.
        view: ``(N,)`` view of each pose; a group holds at most one pose per view.
        tau: a candidate joins while its weighted mean affinity ā to the group is >= tau.
        min_score: poses below this confidence neither seed nor join.
        min_group_size: smaller groups are dropped (their poses count as visited).
    Returns:
        groups: arrays of pose indices, in the order they were built (seeds first).

    Memory: ``A`` is only read, one row per pose (``O(N)`` extra); time ``O(N²)``.
    """
    N = len(score)
    if A.shape != (N, N) or view.shape != (N,):
        raise ValueError(f"greedy_groups: expected A (N, N) and view (N,) with N = {N}, "
                         f"got {A.shape} and {view.shape}")
    w = np.asarray(score, dtype=float)
    w = np.where(np.isfinite(w), w, 0.0)
    available = w >= min_score
    groups: list[np.ndarray] = []
    for seed in np.argsort(-w, kind="stable"):
        if not available[seed]:
            continue
        available[seed] = False
        members = grow_group(A, w, view, available, int(seed), tau)
        available[members] = False
        if len(members) >= min_group_size:
            groups.append(members)
    return groups


def _affinity_row(A: np.ndarray, x: int, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Affinities of pose ``x`` to ``columns`` (undefined -> 0) and where they are defined,
    ``(C,)`` float32 each. Each pose's row is read once (as seed or as member): no ``N × N`` temporary."""
    a = np.asarray(A[x, columns], dtype=np.float32)
    defined = ~np.isnan(a)
    return np.where(defined, a, np.float32(0)), defined.astype(np.float32)


def grow_group(A: np.ndarray, w: np.ndarray, view: np.ndarray, available: np.ndarray, seed: int,
               tau: float) -> np.ndarray:
    """One group of Algorithm 1 grown from ``seed``: candidates are the ``available: (N,)``
    poses of other views; the one with the largest weighted sum of affinities joins while
    its weighted mean affinity ā is >= ``tau``. ``w: (N,)`` confidences. Returns the members
    (seed first)."""
    candidates = np.flatnonzero(available & (view != view[seed]))
    a, defined = _affinity_row(A, seed, candidates)
    weighted_sum = w[seed] * a                                       # Σ_p w_p A(x, p)
    total_weight = w[seed] * defined                                 # Σ_p w_p [A defined]
    members = [seed]
    open_ = np.ones(len(candidates), dtype=bool)
    cand_w = w[candidates]
    cand_view = view[candidates]
    while open_.any():
        gain = np.where(open_, cand_w * weighted_sum, -np.inf)    # the paper's sum
        best = int(np.argmax(gain))
        if not weighted_sum[best] >= tau * total_weight[best] or total_weight[best] == 0:
            break
        x = candidates[best]
        members.append(x)
        open_ &= cand_view != cand_view[best]
        a, defined = _affinity_row(A, x, candidates)
        weighted_sum += w[x] * a
        total_weight += w[x] * defined
    return np.array(members)
