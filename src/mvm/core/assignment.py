"""Minimum-cost assignment of small cost matrices without importing scipy.

:func:`min_cost_assignment` is :func:`scipy.optimize.linear_sum_assignment` (a full matching of
the smaller side, the sum of its costs least) for the matrices a scene's association meets: a
few 2D poses of one view that claim the same few persons, the persons of one rig instant and
the tracks they may continue. Where every row's cheapest column is a different column, that is
the matching; otherwise the matchings are enumerated at once in numpy (at most
:data:`MAX_ENUMERATED` of them); only larger ones import scipy, whose ``scipy.optimize`` costs
0.4–0.9 s to import: more than a hundred small scenes.
"""
from __future__ import annotations

import functools
import itertools
import math

import numpy as np

#: Largest number of matchings enumerated; a larger matrix goes to scipy.
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
        from scipy.optimize import linear_sum_assignment

        return linear_sum_assignment(cost)
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
