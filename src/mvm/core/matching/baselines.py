"""The paper's baselines for grouping 2D poses (Table 1), on the same affinity matrix as the
greedy Algorithm 1.

- :func:`hungarian_groups`: sequential frame-to-frame matching, the Hungarian algorithm on the
  affinity of each track's last pose and the poses of the next frame (the paper's "Hungarian
  + MSE" when the affinity comes from the 2D MSE distance).
- :func:`shortest_path_groups`: tracks as successive shortest paths through the frames, in the
  manner of Arnab et al. (CVPR 2019): a path's cost sums ``-log(2A)`` over its links minus a
  reward per link, so the best path is the longest chain of confident links.
- :func:`dong_groups`: cycle-consistent multi-way matching of the whole affinity matrix as in
  Dong et al. (CVPR 2019): a low-rank (nuclear norm), block doubly-stochastic relaxation
  solved by ADMM, then the connected components of the rounded result.

Every function takes ``A: (N, N)`` affinities in [0, 0.5] (NaN: undefined), the poses'
``score: (N,)`` and ``view: (N,)`` (views are frames in capture order), and returns groups:
arrays of pose indices, at most one pose per view each.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from mvm.core.config import check_settings, setting

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BaselineConfig:
    """Settings of the baselines (the greedy method's are in :class:`mvm.core.config.Config`)."""

    #: Hungarian and shortest path: two poses are linked only when their affinity is at least
    #: this; lower links more (and more wrongly). [affinity, 0-0.5]
    link_affinity: float = setting(0.1, ge=0, le=0.5)
    #: Hungarian and shortest path: a track may skip this many frames without a pose. [frames]
    max_gap_frames: int = setting(3, ge=0)
    #: Dong: affinities (as 2A in [0, 1]) below this are pushed towards no match (W = α - 2A). [1]
    dong_alpha: float = setting(0.1, ge=0, le=1)
    #: Dong: weight λ of the nuclear norm (low rank = few persons); higher finds fewer persons. [1]
    dong_lambda: float = setting(50.0, ge=0)
    #: Dong: initial ADMM penalty μ (adapted while iterating). [1]
    dong_mu: float = setting(64.0, gt=0)
    #: Dong: iteration cap of ADMM; fewer is faster and less converged. [iterations]
    dong_max_iterations: int = setting(500, ge=1)
    #: Dong: convergence tolerance of the primal and dual residuals; lower iterates longer. [1]
    dong_tolerance: float = setting(5e-4, gt=0)
    #: Dong: alternating row/column normalisations per projection onto the block
    #: doubly-stochastic set. [steps]
    dong_projection_steps: int = setting(5, ge=1)

    def __post_init__(self):
        check_settings(self)


def _clean(A: np.ndarray, score: np.ndarray, view: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    N = len(score)
    A = np.asarray(A, dtype=float)
    view = np.asarray(view)
    if A.shape != (N, N) or view.shape != (N,):
        raise ValueError(f"expected A (N, N) and view (N,) with N = {N}, got {A.shape} and {view.shape}")
    A = np.where(np.isfinite(A), A, 0.0)
    A[view[:, None] == view[None, :]] = 0.0
    return A, np.asarray(score, dtype=float), view


def _keep(groups: list[np.ndarray], min_group_size: int) -> list[np.ndarray]:
    return [np.asarray(g, dtype=int) for g in groups if len(g) >= min_group_size]


def hungarian_groups(A: np.ndarray, score: np.ndarray, view: np.ndarray, link_affinity: float = 0.1,
                     max_gap_frames: int = 3, min_score: float = 0.0, min_group_size: int = 1) -> list[np.ndarray]:
    """Sequential matching. ``A: (N, N)``, ``score, view: (N,)`` -> groups.

    Frames are visited in order; the poses of a frame are assigned to the tracks seen within
    the last ``max_gap_frames`` frames by the Hungarian algorithm on the affinity of each
    track's last pose; an assignment below ``link_affinity`` starts a new track instead.
    """
    A, score, view = _clean(A, score, view)
    usable = score >= min_score
    tracks: list[list[int]] = []
    last = np.zeros(0, dtype=int)
    for v in np.unique(view[usable]):
        rows = np.flatnonzero(usable & (view == v))
        active = np.flatnonzero(view[last] >= v - max_gap_frames) if len(last) else np.zeros(0, dtype=int)
        assigned = np.zeros(len(rows), dtype=bool)
        if len(active):
            gain = A[np.ix_(last[active], rows)]                                   # (T, n_v)
            t_idx, r_idx = linear_sum_assignment(-gain)
            ok = gain[t_idx, r_idx] >= link_affinity
            for t, r in zip(active[t_idx[ok]], r_idx[ok]):
                tracks[t].append(int(rows[r]))
                last[t] = rows[r]
            assigned[r_idx[ok]] = True
        new = rows[~assigned]
        tracks += [[int(r)] for r in new]
        last = np.concatenate([last, new])
    return _keep(tracks, min_group_size)


def shortest_path_groups(A: np.ndarray, score: np.ndarray, view: np.ndarray, link_affinity: float = 0.1,
                         max_gap_frames: int = 3, min_score: float = 0.0,
                         min_group_size: int = 1) -> list[np.ndarray]:
    """Successive shortest paths through the frames. ``A: (N, N)``, ``score, view: (N,)`` -> groups.

    A link joins poses of frames ``u < v <= u + max_gap_frames`` with ``A >= link_affinity``
    and costs ``-log(2A) + log(2 link_affinity)`` (<= 0). The cheapest path (dynamic
    programming over the frames, a DAG) becomes a group and its poses leave the graph; this
    repeats until no link is left.
    """
    A, score, view = _clean(A, score, view)
    usable = score >= min_score
    with np.errstate(divide="ignore"):
        cost = -np.log(2 * np.maximum(A, 1e-300)) + np.log(2 * link_affinity)
    frames = np.unique(view[usable])
    allowed = (A >= link_affinity) & (view[None, :] > view[:, None]) & (view[None, :] <= view[:, None] + max_gap_frames)
    cost = np.where(allowed, cost, np.inf)
    rows_of = {v: np.flatnonzero(usable & (view == v)) for v in frames}
    alive = usable.copy()
    groups: list[np.ndarray] = []
    while True:
        best = np.zeros(len(A))
        pred = np.full(len(A), -1)
        window: list[np.ndarray] = []
        for v in frames:
            rows = rows_of[v][alive[rows_of[v]]]
            window = [w for w in window if len(w) and view[w[0]] >= v - max_gap_frames]
            if len(rows) and window:
                prev = np.concatenate(window)
                total = best[prev, None] + cost[np.ix_(prev, rows)]                    # (n_prev, n_v)
                arg = np.argmin(total, axis=0)
                value = total[arg, np.arange(len(rows))]
                better = value < 0
                best[rows] = np.where(better, value, 0.0)
                pred[rows] = np.where(better, prev[arg], -1)
            if len(rows):
                window.append(rows)
        end = int(np.argmin(np.where(alive, best, np.inf)))
        if not best[end] < 0:
            break
        path = [end]
        while pred[path[-1]] >= 0:
            path.append(int(pred[path[-1]]))
        path = np.array(path[::-1])
        alive[path] = False
        groups.append(path)
    groups += [np.array([i]) for i in np.flatnonzero(alive)]
    return _keep(groups, min_group_size)


def _block_starts(view_sorted: np.ndarray) -> np.ndarray:
    return np.flatnonzero(np.r_[True, view_sorted[1:] != view_sorted[:-1]])


def project_block_stochastic(X: np.ndarray, starts: np.ndarray, steps: int) -> np.ndarray:
    """Push ``X: (N, N)`` (poses sorted by view, blocks starting at ``starts``) towards the set
    where every row and every column of every view-pair block sums to at most 1, by
    alternating row and column normalisation (``steps`` rounds)."""
    block = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(X)]))
    for _ in range(steps):
        rows = np.add.reduceat(X, starts, axis=1)                                     # (N, B)
        X = X / np.maximum(rows, 1.0)[:, block]
        cols = np.add.reduceat(X, starts, axis=0)                                     # (B, N)
        X = X / np.maximum(cols, 1.0)[block, :]
    return X


def dong_matching(S: np.ndarray, view: np.ndarray, config: BaselineConfig = BaselineConfig()) -> tuple[np.ndarray, int]:
    """Dong et al.'s convex multi-way matching. ``S: (N, N)`` affinities in [0, 1] of poses
    sorted by view, ``view: (N,)`` -> the relaxed partial permutation matrix ``X: (N, N)`` and
    the iterations run.

    ADMM on ``min <W, X> + λ ||Q||_*`` s.t. ``X = Q``, ``X`` symmetric in [0, 1] with identity
    diagonal, zero blocks within a view and block doubly-stochastic, ``W = α - S``. The
    nuclear norm's proximal step is a singular value thresholding (an eigendecomposition: the
    iterates are symmetric). Cost: one ``O(N³)`` eigendecomposition per iteration.
    """
    N = len(S)
    starts = _block_starts(view)
    same_view = view[:, None] == view[None, :]
    S = 0.5 * (S + S.T)
    np.fill_diagonal(S, 0.0)
    X = S.copy()
    Y = np.zeros_like(S)
    W = config.dong_alpha - S
    mu = config.dong_mu
    iteration = 0
    for iteration in range(1, config.dong_max_iterations + 1):  # noqa: B007 (returned: the iterations run)
        X_prev = X
        eigenvalues, vectors = np.linalg.eigh(Y / mu + X)
        shrunk = np.sign(eigenvalues) * np.maximum(np.abs(eigenvalues) - config.dong_lambda / mu, 0.0)
        keep = shrunk != 0
        Q = (vectors[:, keep] * shrunk[keep]) @ vectors[:, keep].T
        X = Q - (W + Y) / mu
        X[same_view] = 0.0
        np.fill_diagonal(X, 1.0)
        X = np.clip(X, 0.0, 1.0)
        X = project_block_stochastic(X, starts, config.dong_projection_steps)
        X[same_view] = 0.0
        np.fill_diagonal(X, 1.0)
        X = 0.5 * (X + X.T)
        Y = Y + mu * (X - Q)
        primal = np.linalg.norm(X - Q) / N
        dual = mu * np.linalg.norm(X - X_prev) / N
        if primal < config.dong_tolerance and dual < config.dong_tolerance:
            break
        if primal > 10 * dual:
            mu *= 2
        elif dual > 10 * primal:
            mu /= 2
    return X, iteration


def dong_groups(A: np.ndarray, score: np.ndarray, view: np.ndarray, config: BaselineConfig = BaselineConfig(),
                min_score: float = 0.0, min_group_size: int = 1) -> list[np.ndarray]:
    """Groups from :func:`dong_matching` on ``2A``. ``A: (N, N)``, ``score, view: (N,)`` -> groups.

    The relaxed matrix is rounded at 0.5; each connected component is a person, keeping one
    pose per view (the one most strongly matched to the rest of the component).
    """
    A, score, view = _clean(A, score, view)
    usable = np.flatnonzero(score >= min_score)
    order = usable[np.argsort(view[usable], kind="stable")]
    if len(order) == 0:
        return []
    X, iterations = dong_matching(2 * A[np.ix_(order, order)], view[order], config)
    log.debug("Dong matching: %d poses, %d iterations", len(order), iterations)
    link = X > 0.5
    np.fill_diagonal(link, False)
    _, component = connected_components(coo_matrix(link), directed=False)
    groups = []
    for c in np.unique(component):
        members = np.flatnonzero(component == c)
        strength = X[np.ix_(members, members)].sum(axis=1)
        members = members[np.argsort(-strength, kind="stable")]
        _, first = np.unique(view[order[members]], return_index=True)
        kept = np.sort(members[first])
        groups.append(order[kept])
        groups += [np.array([order[m]]) for m in np.setdiff1d(members, kept)]
    return _keep(groups, min_group_size)
