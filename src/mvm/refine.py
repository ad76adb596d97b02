"""Refinement of triangulated poses (the paper's Eq. bundle):

    min_X  Σ_u ρ(‖π_u(X) − x_u‖²) · c_u  +  λ · E_P(X),   E_P(X) = −log Σ_l w_l N(X̃ | μ_l, Σ_l)

with ρ the soft-L1 robust loss of scale ``f`` pixels, ``c_u`` the keypoint confidences, X̃
the root-relative, scale-normalized pose in its own body frame (:mod:`mvm.prior`) and λ the
prior weight. It is solved with ``scipy.optimize.least_squares`` (trust region, LSMR) on an
analytic sparse Jacobian whose pattern is built once per outer iteration:

- each 2D keypoint gives two rows that depend on the 3 coordinates of its joint only;
- each person's prior rows depend on that person's coordinates only (a dense block).

Outer iterations re-linearize what the inner problem holds fixed: the robust weights
(iteratively reweighted least squares for ρ), the body frame and scale of the
canonicalization, and the mixture component (the max-mixture approximation of E_P, whose
negative log-likelihood of one component is a sum of squares). Persons are independent, so
one solve refines all of them at once.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares

from .geometry import project
from .keypoints import LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER
from .prior import body_frame

log = logging.getLogger(__name__)


@dataclass
class RefineResult:
    """``X: (P, J, 3)`` refined poses; ``fallback: (P,)`` bool, persons kept at their
    triangulation because refinement made them worse; ``cost_before/after``: the objective."""

    X: np.ndarray
    fallback: np.ndarray
    cost_before: float
    cost_after: float


def _prior_block(X: np.ndarray, present: np.ndarray, prior) -> tuple[np.ndarray, np.ndarray] | None:
    """Linearized prior of one person: ``(G (K, 3n), h (K,))`` with residual ``G x - h`` for the
    ``n`` present joints' world coordinates ``x`` (joint-major), or None without hips/shoulders."""
    needed = [LEFT_HIP, RIGHT_HIP, LEFT_SHOULDER, RIGHT_SHOULDER]
    if not present[needed].all():
        return None
    rotation, _, scale = body_frame(X)                # rows: the body axes in the world
    if not np.isfinite(rotation).all() or not scale > 0:
        return None
    joints = np.flatnonzero(present)
    n = len(joints)
    # y_j = R (X_j - (X_lh + X_rh) / 2) / s  ->  y = B x with B = C ⊗ (R / s), the prior's
    # canonicalization with its frame held fixed for this outer iteration.
    C = np.eye(n)
    C[:, np.searchsorted(joints, LEFT_HIP)] -= 0.5
    C[:, np.searchsorted(joints, RIGHT_HIP)] -= 0.5
    B = np.kron(C, rotation / scale)
    canonical = np.full((1, X.shape[0], 3), np.nan)
    canonical[0, joints] = (B @ X[joints].reshape(-1)).reshape(n, 3)
    component = int(prior.best_component(canonical)[0])
    mean, W, _ = prior.whitening(present, component)
    return W @ B, W @ mean


def refine_poses(X0: np.ndarray, xy: np.ndarray, conf: np.ndarray, P: np.ndarray, inliers: np.ndarray,
                 prior=None, prior_weight: float = 10.0, robust_scale_px: float = 5.0,
                 max_iterations: int = 30, outer_iterations: int = 3) -> RefineResult:
    """Refine ``P`` persons' 3D joints.

    Args:
        X0: ``(P, J, 3)`` triangulated joints (NaN: not reconstructed, stays NaN).
        xy: ``(P, M, J, 2)`` keypoints; conf: ``(P, M, J)`` confidences.
        P: ``(P, M, 3, 4)`` projection matrices of the views.
        inliers: ``(P, M, J)`` bool, the keypoints to fit.
        prior: a :class:`mvm.prior.PosePrior` or None (reprojection only).
        prior_weight: λ, pixels² per nat.
        robust_scale_px: scale ``f`` of the soft-L1 loss.
    Returns:
        :class:`RefineResult`.
    """
    X0 = np.asarray(X0, dtype=float)
    Pn, J, _ = X0.shape
    present = np.isfinite(X0).all(-1)                                    # (P, J)
    param_of = -np.ones((Pn, J), dtype=int)
    param_of[present] = np.arange(present.sum())
    n_params = 3 * int(present.sum())
    use = inliers & present[:, None, :]
    p_idx, m_idx, j_idx = np.nonzero(use)
    if n_params == 0 or len(p_idx) == 0:
        return RefineResult(X0.copy(), np.zeros(Pn, bool), 0.0, 0.0)
    obs_param = param_of[p_idx, j_idx]                                   # (K,)
    obs_P = P[p_idx, m_idx]                                              # (K, 3, 4)
    obs_xy = xy[p_idx, m_idx, j_idx]                                     # (K, 2)
    obs_c = conf[p_idx, m_idx, j_idx]
    K = len(obs_param)
    rows_reproj = np.repeat(np.arange(2 * K), 3)
    cols_reproj = (3 * np.repeat(obs_param, 2)[:, None] + np.arange(3)).reshape(-1)

    # Parameter columns of each person's present joints (joint-major x, y, z).
    person_cols = [3 * np.repeat(param_of[p][present[p]], 3) + np.tile(np.arange(3), present[p].sum())
                   for p in range(Pn)]
    use_prior = prior is not None and prior_weight > 0

    def unpack(x):
        X = np.full((Pn, J, 3), np.nan)
        X[present] = x.reshape(-1, 3)
        return X

    def reprojection(x):
        """Residual pixels ``(K, 2)`` and depths ``(K,)`` of the fitted keypoints."""
        uv, depth = project(x.reshape(-1, 3)[obs_param], obs_P)
        return uv - obs_xy, depth

    def prior_terms(X):
        """Linearized prior of every person: ``[(cols, G, h)]`` with residual ``G x[cols] − h``
        (already scaled by sqrt(λ))."""
        if not use_prior:
            return []
        terms = []
        for p in range(Pn):
            block = _prior_block(X[p], present[p], prior)
            if block is not None:
                G, h = block
                terms.append((person_cols[p], np.sqrt(prior_weight) * G, np.sqrt(prior_weight) * h))
        return terms

    def objective(x, terms):
        """Σ c ρ(e²) + λ E_P (up to the mixture's constants)."""
        e, _ = reprojection(x)
        f2 = robust_scale_px**2
        total = (obs_c * 2 * f2 * (np.sqrt(1 + (e**2).sum(-1) / f2) - 1)).sum()
        return float(total + sum(0.5 * np.sum((G @ x[cols] - h) ** 2) for cols, G, h in terms))

    x = X0[present].reshape(-1).copy()
    cost_before = objective(x, prior_terms(X0))

    for _ in range(outer_iterations):
        e, _ = reprojection(x)
        robust_w = 1.0 / np.sqrt(1.0 + (e**2).sum(-1) / robust_scale_px**2)   # ρ'(e²) of soft-L1
        sqrt_w = np.repeat(np.sqrt(2.0 * robust_w * obs_c), 2)                 # (2K,)
        terms = prior_terms(unpack(x))
        # The Jacobian's sparsity pattern: 3 entries per reprojection row, a dense block per
        # person's prior rows.
        starts = 2 * K + np.cumsum([0] + [len(G) for _, G, _ in terms])
        rows = np.concatenate([rows_reproj] + [np.repeat(np.arange(a, a + len(G)), len(cols))
                                               for a, (cols, G, _) in zip(starts, terms)])
        cols_all = np.concatenate([cols_reproj] + [np.tile(cols, len(G)) for cols, G, _ in terms])
        prior_values = np.concatenate([np.zeros(0)] + [G.reshape(-1) for _, G, _ in terms])
        shape = (int(starts[-1]), n_params)

        def residuals(x):
            e, _ = reprojection(x)
            return np.concatenate([sqrt_w * e.reshape(-1)] + [G @ x[cols] - h for cols, G, h in terms])

        def jacobian(x):
            homogeneous = np.concatenate([x.reshape(-1, 3)[obs_param], np.ones((K, 1))], axis=1)
            proj = np.einsum("kab,kb->ka", obs_P, homogeneous)
            z = proj[:, 2:3]
            uv = proj[:, :2] / z
            d = (obs_P[:, :2, :3] - uv[:, :, None] * obs_P[:, 2:3, :3]) / z[:, :, None]   # (K, 2, 3)
            values = (d * sqrt_w.reshape(K, 2)[:, :, None]).reshape(-1)
            return sp.csr_matrix((np.concatenate([values, prior_values]), (rows, cols_all)), shape=shape)

        x = least_squares(residuals, x, jac=jacobian, method="trf", tr_solver="lsmr",
                          x_scale="jac", max_nfev=max_iterations).x

    X = unpack(x)
    fallback = np.zeros(Pn, dtype=bool)
    e0, _ = reprojection(X0[present].reshape(-1))
    e1, depth1 = reprojection(x)
    err0 = np.linalg.norm(e0, axis=-1)
    err1 = np.linalg.norm(e1, axis=-1)
    for p in range(Pn):
        rows_p = p_idx == p
        if not rows_p.any():
            continue
        finite = np.isfinite(X[p][present[p]]).all()
        worse = np.median(err1[rows_p]) > 2.0 * np.median(err0[rows_p]) + robust_scale_px
        behind = (depth1[rows_p] <= 0).any()
        if not finite or worse or behind:
            fallback[p] = True
            X[p] = X0[p]
    if fallback.any():
        log.warning("refinement diverged for %d person(s); kept their triangulation", int(fallback.sum()))
    x_final = X[present].reshape(-1)
    return RefineResult(X, fallback, cost_before, objective(x_final, prior_terms(X)))
