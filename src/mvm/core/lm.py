"""A batched Levenberg-Marquardt solver for many small, independent least-squares problems.

``P`` problems of ``n`` unknowns each (e.g. the persons of a scene and their joints) are
solved together: every problem has its own damping, accepts or rejects its own steps and
stops on its own tolerance, with the ``ftol`` / ``xtol`` meaning of
``scipy.optimize.least_squares``, or as soon as a bound on what any step could still gain
falls under it. A step solves only the problems still active, and each trial point is
evaluated once, its normal equations with its cost.

The solver knows nothing of the residuals: a :class:`BatchedLeastSquares` problem builds its
normal equations and solves its damped systems (their layout is its own), and the solver
handles the arrays ``x: (P, n)``, costs and dampings.
"""
from __future__ import annotations

from typing import Protocol

import numpy as np

#: Initial damping of every problem, relative to the diagonal of its normal equations.
INITIAL_DAMPING = 1e-3
_MIN_DAMPING, _MAX_DAMPING = 1e-9, 1e12


class BatchedLeastSquares(Protocol):
    """``P`` independent problems ``min_x ½ |r_p(x_p)|²`` with ``x: (P, n)``.

    ``curvature`` is whatever the problem keeps of ``Jrᵀ Jr`` to solve its damped systems, an
    array whose first axis is the ``P`` problems; the solver only selects its rows."""

    def normal_equations(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """At ``x: (P, n)``: the cost ``½|r|²: (P,)``, the gradient ``Jrᵀ r: (P, n)``, the
        ``curvature: (P, ...)`` and ``reach: (P,)``, an upper bound on the decrease any step
        can bring the Gauss-Newton model (``inf`` where none is known)."""
        ...

    def damped_steps(self, curvature: np.ndarray, grad: np.ndarray, damping: np.ndarray) -> np.ndarray:
        """The steps ``δ: (P, n)`` of ``(H + μ diag(H)) δ = −grad`` with ``H = Jrᵀ Jr`` from
        ``curvature: (P, ...)``, ``grad: (P, n)`` and ``damping μ: (P,)``."""
        ...

    def take(self, problems: np.ndarray) -> BatchedLeastSquares:
        """The problems of ``problems: (Q,)`` indices, in that order."""
        ...


def levenberg_marquardt(x: np.ndarray, problem: BatchedLeastSquares, max_steps: int,
                        tolerance: float) -> np.ndarray:
    """Minimize every problem's half sum of squared residuals from ``x: (P, n)``; returns ``(P, n)``.

    Each problem has its own damping (relative to its normal equations' diagonal: divided by 3
    after an accepted step, multiplied by 10 after a rejected one) and stops on its own when
    no step can lower its Gauss-Newton model by more than ``tolerance`` times its cost (the
    ``reach`` of :meth:`BatchedLeastSquares.normal_equations`, checked wherever the normal
    equations are built, so a converged problem costs no solve), when an accepted step lowers
    its cost by less than that, or a step is shorter than ``tolerance · (tolerance + |x_p|)``
    (the ``ftol`` and ``xtol`` of ``scipy.optimize.least_squares``), or after ``max_steps``
    steps. A trial point gets its normal equations with its cost (most steps are accepted: one
    evaluation per step), kept where the step is accepted; only the problems still active are
    solved. A problem whose cost is not finite at ``x`` is not moved."""
    x = x.copy()
    cost, grad, curvature, reach = problem.normal_equations(x)
    damping = np.full(len(x), INITIAL_DAMPING)
    active = np.isfinite(cost) & ~(reach <= tolerance * cost)
    sub, idx = problem, np.arange(len(x))
    for _ in range(max_steps):
        if not active.any():
            break
        if not active[idx].all():
            idx = np.flatnonzero(active)
            sub = problem.take(idx)
        start, current, mu = x[idx], cost[idx], damping[idx]
        step = sub.damped_steps(curvature[idx], grad[idx], mu)
        trial = start + step
        trial_cost, trial_grad, trial_curvature, reach = sub.normal_equations(trial)
        better = trial_cost < current
        small_step = _norms(step) <= tolerance * (tolerance + _norms(start))
        small_gain = better & (current - trial_cost <= tolerance * current)
        damping[idx] = np.clip(np.where(better, mu / 3.0, mu * 10.0), _MIN_DAMPING, _MAX_DAMPING)
        active[idx] = ~(small_step | small_gain)
        x[idx[better]], cost[idx[better]] = trial[better], trial_cost[better]
        moved = better & active[idx]
        grad[idx[moved]], curvature[idx[moved]] = trial_grad[moved], trial_curvature[moved]
        active[idx[moved]] = ~(reach[moved] <= tolerance * trial_cost[moved])
    return x


def spd_solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``x: (P, n)`` with ``A x = b`` for ``A: (P, n, n)`` (damped normal equations,
    symmetric positive definite; not modified), ``b: (P, n)``: numpy's batched LAPACK solve.
    numpy rather than scipy's Cholesky (``posv``): importing scipy.linalg costs more than the
    whole refinement of a rig sequence, and the solve count matters more than the routine. A
    batch holding an exactly singular matrix is solved matrix by matrix, that one by least
    squares.

    >>> A = np.array([[[2.0, 0.0], [0.0, 4.0]], [[1.0, 0.0], [0.0, 0.0]]])     # the second is singular
    >>> spd_solve(A, np.array([[2.0, 2.0], [3.0, 0.0]]))
    array([[1. , 0.5],
           [3. , 0. ]])
    """
    try:
        return np.linalg.solve(A, b[..., None])[..., 0]
    except np.linalg.LinAlgError:
        x = np.empty(b.shape)
        for p in range(len(A)):
            try:
                x[p] = np.linalg.solve(A[p], b[p])
            except np.linalg.LinAlgError:
                x[p] = np.linalg.lstsq(A[p], b[p], rcond=None)[0]
        return x


def _norms(x: np.ndarray) -> np.ndarray:
    """Euclidean norms of the rows of ``x: (P, n)``, ``(P,)``."""
    return np.sqrt(np.einsum("pn,pn->p", x, x))
