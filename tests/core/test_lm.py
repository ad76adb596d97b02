"""The batched Levenberg-Marquardt solver on a problem of its own (not the refinement's): each
of ``P`` noisy exponential decays ``y = a exp(-b t)`` fitted independently, against the
parameters the data were made from and against scipy's solver, problem by problem."""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from mvm.core.lm import levenberg_marquardt, spd_solve

T = np.linspace(0.0, 3.0, 25)


class Decays:
    """``P`` fits of ``(a, b)``: residuals ``a exp(-b t) − y``, ``y: (P, T)``."""

    def __init__(self, y: np.ndarray, evaluations: list | None = None):
        self.y = y
        self.evaluations = [0] if evaluations is None else evaluations    # problems evaluated, shared by take

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return x[:, :1] * np.exp(-x[:, 1:] * T) - self.y

    def normal_equations(self, x):
        self.evaluations[0] += len(x)
        r = self.residuals(x)
        e = np.exp(-x[:, 1:] * T)
        J = np.stack([e, -x[:, :1] * T * e], axis=2)                      # (P, T, 2)
        H = np.einsum("pti,ptj->pij", J, J)
        return 0.5 * (r**2).sum(1), np.einsum("pti,pt->pi", J, r), H, np.full(len(x), np.inf)

    def damped_steps(self, H, grad, damping):
        A = H.copy()
        A[:, [0, 1], [0, 1]] *= 1.0 + damping[:, None]
        return -spd_solve(A, grad)

    def take(self, problems):
        return Decays(self.y[problems], self.evaluations)


def test_every_problem_reaches_its_own_least_squares_fit():
    rng = np.random.default_rng(4)
    truth = np.column_stack([rng.uniform(1, 5, 6), rng.uniform(0.3, 2.0, 6)])
    y = truth[:, :1] * np.exp(-truth[:, 1:] * T) + rng.normal(0, 0.01, (6, len(T)))
    problem = Decays(y)
    x0 = np.column_stack([np.ones(6), np.full(6, 1.0)])
    ours = levenberg_marquardt(x0, problem, 200, 1e-12)
    assert np.abs(ours - truth).max() < 0.05                                  # the parameters of the data
    for p in range(6):
        theirs = least_squares(lambda v: Decays(y[p:p + 1]).residuals(v[None])[0],  # noqa: B023 (called here)
                               x0[p], method="lm", ftol=1e-14, xtol=1e-14).x
        np.testing.assert_allclose(ours[p], theirs, atol=1e-7)
    batched = ours
    alone = np.concatenate([levenberg_marquardt(x0[p:p + 1], Decays(y[p:p + 1]), 200, 1e-12) for p in range(6)])
    np.testing.assert_array_equal(batched, alone)                            # problems are independent


def test_a_converged_problem_stops_and_a_non_finite_one_is_not_moved():
    y = 2.0 * np.exp(-0.5 * T)[None].repeat(2, 0)
    x0 = np.array([[2.0, 0.5], [np.nan, 1.0]])                              # at its minimum; not finite
    problem = Decays(y)
    x = levenberg_marquardt(x0, problem, 50, 1e-10)
    np.testing.assert_array_equal(x[0], x0[0])
    assert np.isnan(x[1, 0]) and x[1, 1] == 1.0
    assert problem.evaluations[0] == 3                      # both at the start, then one step of the finite one
