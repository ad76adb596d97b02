"""Minimum-cost assignment of small cost matrices without importing scipy.

:func:`min_cost_assignment` is :func:`scipy.optimize.linear_sum_assignment` (a full matching of
the smaller side, the sum of its costs least) for the matrices a scene's association meets: a
few 2D poses of one view that claim the same few persons, the persons of one rig instant and
the tracks they may continue. Where every row's cheapest column is a different column, that is
the matching; otherwise the matchings are enumerated at once in numpy (at most
:data:`MAX_ENUMERATED` of them); larger ones are solved by shortest augmenting paths
(:func:`_augmenting_paths`, the algorithm of scipy's own solver, one numpy pass per step). scipy
is not imported: ``scipy.optimize`` costs 0.4–0.9 s to import, more than a whole small scene.
"""
from __future__ import annotations

import functools
import itertools
import math

import numpy as np

#: Largest number of matchings enumerated; a larger matrix is solved by augmenting paths.
MAX_ENUMERATED = 5040


def min_cost_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of a minimum-cost full matching of the smaller side of ``cost: (n, m)``.

    Returns ``(rows, cols)``, two ``(min(n, m),)`` index arrays with ``rows`` increasing, as
    :func:`scipy.optimize.linear_sum_assignment` does (ties between equal sums may be broken
    differently). Costs must be finite.

    >>> min_cost_assignment(np.array([[4.0, 1, 3], [2, 0, 5], [3, 2, 2]]))
    (array([0, 1, 2]), array([1, 0, 2]))
    """
    cost = np.asarray(cost, dtype=float)
    if cost.ndim != 2:
        raise ValueError(f"min_cost_assignment: expected a (n, m) matrix, got shape {cost.shape}")
    n, m = cost.shape
    if min(n, m) == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    if n <= m:                               # every row at its cheapest column, all different: optimal
        best = np.argmin(cost, axis=1)
        if len(np.unique(best)) == n:
            return np.arange(n), best
    if math.perm(max(n, m), min(n, m)) > MAX_ENUMERATED:
        if n <= m:
            return np.arange(n), _augmenting_paths(cost)
        rows = _augmenting_paths(cost.T)
        order = np.argsort(rows)
        return rows[order], order
    if n <= m:
        cols = _matchings(m, n)[np.argmin(cost[np.arange(n), _matchings(m, n)].sum(1))]
        return np.arange(n), cols
    rows = _matchings(n, m)[np.argmin(cost[_matchings(n, m), np.arange(m)].sum(1))]
    order = np.argsort(rows)
    return rows[order], np.arange(m)[order]


@functools.lru_cache(maxsize=64)
def _matchings(m: int, n: int) -> np.ndarray:
    """``(m! / (m - n)!, n)`` every injective map of ``n`` items into ``m``, read-only."""
    table = np.array(list(itertools.permutations(range(m), n)), dtype=np.intp).reshape(-1, n)
    table.flags.writeable = False
    return table


def _augmenting_paths(cost: np.ndarray) -> np.ndarray:
    """Column of each row of a minimum-cost matching of every row of ``cost: (n, m)``, ``n <= m``:
    ``(n,)``. Shortest augmenting paths with dual potentials (Jonker-Volgenant, as Crouse's
    rectangular form that scipy implements): one row is added at a time, along the cheapest
    path in reduced costs to a free column; each step of a path is one numpy pass over the columns."""
    n, m = cost.shape
    u, v = np.zeros(n), np.zeros(m)
    col4row, row4col = np.full(n, -1), np.full(m, -1)
    for start in range(n):
        shortest, path = np.full(m, np.inf), np.full(m, -1)
        in_rows, in_cols = np.zeros(n, dtype=bool), np.zeros(m, dtype=bool)
        i, low, sink = start, 0.0, -1
        while sink < 0:
            in_rows[i] = True
            reduced = low + cost[i] - u[i] - v
            better = ~in_cols & (reduced < shortest)
            path[better] = i
            shortest[better] = reduced[better]
            open_cost = np.where(in_cols, np.inf, shortest)
            low = open_cost.min()
            ties = np.flatnonzero(open_cost == low)
            free = ties[row4col[ties] < 0]
            j = free[0] if len(free) else ties[0]                    # a free column first among ties
            in_cols[j] = True
            if row4col[j] < 0:
                sink = j
            else:
                i = row4col[j]
        u[start] += low
        others = in_rows.copy()
        others[start] = False
        u[others] += low - shortest[col4row[others]]
        v[in_cols] -= low - shortest[in_cols]
        j = sink
        while True:                                                  # flip the path's pairs
            i = path[j]
            row4col[j] = i
            col4row[i], j = j, col4row[i]
            if i == start:
                break
    return col4row
