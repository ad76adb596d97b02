"""The batched Levenberg-Marquardt refinement against constructed truth: its normal equations
are the derivatives of its residuals, it reaches the minimum an independent solver reaches, and
persons are independent."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from mvm.core.geometry import project
from mvm.core.keypoints import bone_lengths
from mvm.core.linearized_prior import linearized_prior, prior_energy
from mvm.core.lm import levenberg_marquardt, spd_solve
from mvm.core.prior import canonicalize, shipped_prior
from mvm.core.refine import (
    BoneTerms,
    InnerProblem,
    Observations,
    damped_steps,
    hessian,
    normal_equations,
    refine_poses,
    residuals,
    robust_terms,
)

from helpers import STANDING, random_cameras


def _capture(seed: int, persons: int = 3, views: int = 6, noise: float = 2.0):
    """``persons`` standing people seen by ``views`` cameras with pixel noise and confidences:
    ``truth, X0`` ``(P, 17, 3)`` (``X0`` perturbed by 3 cm), ``xy, conf, P, inliers`` in the slot
    layout of :func:`mvm.core.refine.refine_poses`. The last person misses its nose (joint 0) and
    its last view slot is empty; a few keypoints are not inliers."""
    rng = np.random.default_rng(seed)
    cams = random_cameras(rng, views, arc_deg=70)
    truth = STANDING[None] + np.array([[0.9 * i, 0.3 * (i % 2), 0.0] for i in range(persons)])[:, None]
    uv, _ = project(truth[:, None], cams.P)                        # (P, V, 17, 2)
    xy = uv + rng.normal(0, noise, uv.shape)
    conf = rng.uniform(0.4, 1.0, uv.shape[:-1])
    P = np.broadcast_to(cams.P[None], (persons, views, 3, 4)).copy()
    inliers = rng.uniform(size=conf.shape) > 0.1
    X0 = truth + rng.normal(0, 0.03, truth.shape)
    X0[-1, 0] = np.nan
    P[-1, -1], inliers[-1, -1], conf[-1, -1] = 0.0, False, 0.0
    return truth, X0, xy, conf, P, inliers


def _inner_problem(X0, xy, conf, P, inliers, truth):
    present = np.isfinite(X0).all(-1)
    X = np.where(present[..., None], X0, 0.0)
    obs = Observations.build(xy, P, conf, inliers & present[:, None])
    bones = BoneTerms.build(bone_lengths(truth) * 1.02, 2e4, present)
    weight = 10.0 * (1.0 + np.arange(len(X)))                                 # each person its own λ
    problem = InnerProblem(obs, robust_terms(obs.reprojection(X)[0], obs, 5.0)[1],
                           linearized_prior(X, present, shipped_prior(), weight), bones)
    return X.reshape(len(X), -1), present, problem


def test_normal_equations_are_the_derivatives_of_the_residuals():
    """Cost, gradient and Gauss-Newton matrix against central differences of the residuals
    (reprojection, linearized prior and bone rows), with an absent joint and an empty slot."""
    truth, X0, xy, conf, P, inliers = _capture(0)
    x, present, problem = _inner_problem(X0, xy, conf, P, inliers, truth)
    x = x + np.where(np.repeat(present, 3, axis=1), np.random.default_rng(1).normal(0, 0.01, x.shape), 0.0)
    cost, grad, blocks, reach = normal_equations(x, problem)
    r = residuals(x, problem)                                                        # (P, R)
    h = 1e-6
    jac = np.stack([(residuals(x + h * e, problem) - residuals(x - h * e, problem)) / (2 * h)
                    for e in np.eye(x.shape[1])], axis=2)                             # (P, R, 51)
    np.testing.assert_allclose(cost, 0.5 * (r**2).sum(1), rtol=1e-12)
    JtJ = np.einsum("pra,prb->pab", jac, jac)
    np.testing.assert_allclose(grad, np.einsum("pra,pr->pa", jac, r), rtol=1e-6, atol=1e-6 * np.abs(grad).max())
    np.testing.assert_allclose(hessian(problem.prior.gram(), blocks), JtJ, rtol=1e-6, atol=1e-7 * np.abs(JtJ).max())
    absent = ~np.repeat(present, 3, axis=1)
    assert absent.sum() == 3 and np.all(jac[absent[:, None, :].repeat(jac.shape[1], 1)] == 0)
    # No step lowers the Gauss-Newton model by more than the bound: ½ gᵀ H⁻¹ g <= reach.
    H = np.where(np.eye(x.shape[1], dtype=bool) & absent[:, None, :], 1.0, JtJ)
    decrease = 0.5 * np.einsum("pa,pa->p", grad, np.linalg.solve(H, grad[..., None])[..., 0])
    assert np.all(decrease <= reach * (1 + 1e-9)) and np.all(reach < 20 * decrease)


def test_damped_steps_in_the_body_basis_are_the_world_steps():
    """The steps solved in each person's body basis are those of the world-frame normal
    equations (without damping, where the two bases' diagonals do not matter)."""
    truth, X0, xy, conf, P, inliers = _capture(6)
    x, present, problem = _inner_problem(X0, xy, conf, P, inliers, truth)
    _, grad, blocks, _ = normal_equations(x, problem)
    H = hessian(problem.prior.gram(), blocks)
    absent = np.eye(x.shape[1], dtype=bool) & ~np.repeat(present, 3, axis=1)[:, None, :]
    expected = -np.linalg.solve(np.where(absent, 1.0, H), grad[..., None])[..., 0]
    steps = damped_steps(problem.prior, blocks, grad, np.zeros(len(x)))
    np.testing.assert_allclose(steps, expected, rtol=1e-7, atol=1e-9 * np.abs(expected).max())
    assert np.all(steps[~np.repeat(present, 3, axis=1)] == 0)


def test_spd_solve_solves_every_system_even_beside_a_singular_one():
    """Every system of the batch is solved (``A x = b``), an indefinite and a negative definite
    one included; a batch holding an exactly singular matrix, which numpy's batched solve
    refuses whole, is solved matrix by matrix, that one in the least-squares sense."""
    rng = np.random.default_rng(5)
    A = rng.normal(size=(5, 9, 9))
    H = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(9)
    H[1] = -H[1]
    H[3, 0, 0] = -50.0
    b = rng.normal(size=(5, 9))
    for singular in (False, True):
        if singular:
            H[2, 4, :] = H[2, :, 4] = 0.0                              # a coordinate nothing depends on
        before = H.copy()
        x = spd_solve(H, b)
        assert np.array_equal(H, before)                                # the systems are left as they were
        for p in range(len(H)):
            if singular and p == 2:
                # least squares: the residual is orthogonal to the columns (and 0 where it can be)
                np.testing.assert_allclose(H[p].T @ (H[p] @ x[p] - b[p]), 0.0, atol=1e-9)
                assert x[p, 4] == pytest.approx(0.0, abs=1e-12)           # the minimum-norm solution
            else:
                np.testing.assert_allclose(H[p] @ x[p], b[p], rtol=1e-9, atol=1e-10)


def test_prior_energy_is_the_linearized_priors_at_its_point():
    """The prior energy of the objective is the linearized prior's energy at the point of
    linearization, and the normal equations' cost that of the residuals, a person without a
    shoulder (no prior) included."""
    truth, X0, xy, conf, P, inliers = _capture(1, persons=4)
    X0[2, 5] = np.nan                                                                # a shoulder: no prior
    x, present, problem = _inner_problem(X0, xy, conf, P, inliers, truth)
    x = x + np.where(np.repeat(present, 3, axis=1), np.random.default_rng(2).normal(0, 0.02, x.shape), 0.0)
    np.testing.assert_allclose(normal_equations(x, problem)[0], 0.5 * (residuals(x, problem) ** 2).sum(1), rtol=1e-12)
    X, prior = x.reshape(len(x), -1, 3), shipped_prior()
    energy = prior_energy(X, present, prior, 10.0)
    canonical = canonicalize(np.where(present[..., None], X, np.nan))     # the prior's own terms, by hand
    component = prior.best_component(canonical)
    for p in (0, 1, 3):
        mean, W, _ = prior.whitening(present[p], int(component[p]))
        r = W @ (canonical[p][present[p]].ravel() - mean)
        assert energy[p] == pytest.approx(0.5 * 10.0 * r @ r, rel=1e-9)
    assert energy[2] == 0.0


def test_levenberg_marquardt_reaches_the_minimum_of_an_independent_solver():
    """The inner problem solved by the batched solver and by scipy's trust-region least squares
    on all persons' present coordinates at once: the same minimum."""
    truth, X0, xy, conf, P, inliers = _capture(2)
    x0, present, problem = _inner_problem(X0, xy, conf, P, inliers, truth)
    ours = levenberg_marquardt(x0, problem, 100, 1e-12)
    free = np.repeat(present, 3, axis=1)

    def stacked(v):
        x = x0.copy()
        x[free] = v
        return residuals(x, problem).ravel()

    theirs = x0.copy()
    theirs[free] = least_squares(stacked, x0[free], method="trf", x_scale="jac", ftol=1e-14, xtol=1e-14,
                                 gtol=1e-14).x
    cost = 0.5 * (residuals(ours, problem) ** 2).sum()
    assert cost <= 0.5 * (residuals(theirs, problem) ** 2).sum() * (1 + 1e-9)
    assert cost < 0.5 * (residuals(x0, problem) ** 2).sum()
    assert np.abs(ours - theirs).max() < 1e-6                                        # metres
    assert np.array_equal(ours[~free], x0[~free])


@pytest.mark.parametrize("with_bones", [False, True])
def test_persons_are_refined_independently(with_bones):
    """Refining persons together gives what refining each alone gives; absent joints stay NaN
    and the refined poses are closer to the truth than the perturbed start."""
    truth, X0, xy, conf, P, inliers = _capture(3)
    lengths = bone_lengths(truth) if with_bones else None
    kwargs = {"prior": shipped_prior(), "bone_weight": 2e4 if with_bones else 0.0, "tolerance": 1e-10}
    together = refine_poses(X0, xy, conf, P, inliers, bone_lengths=lengths, **kwargs)
    for p in range(len(X0)):
        s = slice(p, p + 1)
        alone = refine_poses(X0[s], xy[s], conf[s], P[s], inliers[s],
                             bone_lengths=None if lengths is None else lengths[s], **kwargs)
        np.testing.assert_allclose(alone.X, together.X[s], atol=1e-7)
    assert np.array_equal(np.isnan(together.X), np.isnan(X0))
    assert together.cost_after < together.cost_before
    assert not together.fallback.any()
    error = np.linalg.norm(together.X - truth, axis=-1)
    assert np.nanmean(error) < 0.5 * np.nanmean(np.linalg.norm(X0 - truth, axis=-1))


def test_persons_refined_a_few_at_a_time_come_out_as_all_at_once(monkeypatch):
    """The persons of a long video are refined in chunks (``REFINE_CHUNK``): the poses, the
    costs before and after, and the fallbacks are those of all persons at once (each person
    here its own chunk, one of them pushed behind the cameras)."""
    import mvm.core.refine as refine

    truth, X0, xy, conf, P, inliers = _capture(5)
    centre = np.linalg.inv(P[0, 0, :, :3]) @ -P[0, 0, :, 3]
    X0[2] = 2 * centre - X0[2]                                                       # falls back
    prior, weights = shipped_prior(), np.array([2.0, 40.0, 400.0])
    together = refine_poses(X0, xy, conf, P, inliers, prior, weights, tolerance=1e-10)
    monkeypatch.setattr(refine, "REFINE_CHUNK", 1)
    chunked = refine_poses(X0, xy, conf, P, inliers, prior, weights, tolerance=1e-10)
    np.testing.assert_allclose(chunked.X, together.X, atol=1e-12)
    assert chunked.fallback.tolist() == together.fallback.tolist() == [False, False, True]
    assert chunked.cost_before == pytest.approx(together.cost_before, rel=1e-12)
    assert chunked.cost_after == pytest.approx(together.cost_after, rel=1e-12)


def test_each_persons_prior_weight_is_the_one_it_would_be_refined_alone_with():
    """Per-person prior weights ``(P,)``: each person comes out as refined alone with its own
    weight, and a larger weight holds it closer to the prior (a larger prior energy costs more)."""
    truth, X0, xy, conf, P, inliers = _capture(7)
    prior, weights = shipped_prior(), np.array([2.0, 40.0, 400.0])
    together = refine_poses(X0, xy, conf, P, inliers, prior, weights, tolerance=1e-10)
    for p in range(len(X0)):
        s = slice(p, p + 1)
        alone = refine_poses(X0[s], xy[s], conf[s], P[s], inliers[s], prior, float(weights[p]), tolerance=1e-10)
        np.testing.assert_allclose(alone.X, together.X[s], atol=1e-7)
    present = np.isfinite(X0).all(-1)
    light = refine_poses(X0, xy, conf, P, inliers, prior, 2.0, tolerance=1e-10)
    energy = [prior_energy(np.where(present[..., None], r.X, 0.0), present, prior, 1.0) for r in (light, together)]
    assert energy[1][0] == pytest.approx(energy[0][0], rel=1e-6)                # the same weight
    assert (energy[1][1:] < energy[0][1:]).all()                                # held closer to the prior


def test_a_person_pushed_behind_the_cameras_falls_back_to_its_triangulation():
    """A triangulation behind every camera cannot be refined into view: the person is flagged
    and keeps its joints; the others are refined."""
    _, X0, xy, conf, P, inliers = _capture(4)
    centre = np.linalg.inv(P[0, 0, :, :3]) @ -P[0, 0, :, 3]                          # camera 0's centre
    X0[1] = 2 * centre - X0[1]                                                       # mirrored behind it
    result = refine_poses(X0, xy, conf, P, inliers, shipped_prior())
    assert result.fallback.tolist() == [False, True, False]
    assert np.array_equal(result.X[1], X0[1])
    assert not np.array_equal(result.X[0], X0[0])


def test_robust_weights_are_the_derivative_of_the_robust_cost():
    """IRLS: the gradient of Σ c ρ(|e|²) by the residuals is ``w² e`` with ``w`` the root weights
    (central differences), and the cost is soft-L1's ``2 f² (sqrt(1 + |e|²/f²) − 1)``, each
    keypoint's ``c`` its confidence squared (as the triangulation's weighted DLT)."""
    _, X0, xy, conf, P, inliers = _capture(8)
    present = np.isfinite(X0).all(-1)
    obs = Observations.build(xy, P, conf, inliers & present[:, None])
    e, _ = obs.reprojection(np.where(present[..., None], X0, 0.0))
    cost, w = robust_terms(e, obs, 5.0)
    c = np.where(obs.fit, conf**2, 0.0)
    np.testing.assert_allclose(cost, (c * 50.0 * (np.sqrt(1 + (e**2).sum(-1) / 25.0) - 1)).sum((1, 2)), rtol=1e-12)
    h = 1e-6
    step = np.zeros_like(e)
    step[..., 0] = h
    numeric = (robust_terms(e + step, obs, 5.0)[0] - robust_terms(e - step, obs, 5.0)[0]) / (2 * h)
    np.testing.assert_allclose(numeric, (w**2 * e[..., 0]).sum((1, 2)), rtol=1e-6)
