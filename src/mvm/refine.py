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

log = logging.getLogger(__name__)


@dataclass
class RefineResult:
    """``X: (P, J, 3)`` refined poses; ``fallback: (P,)`` bool, persons kept at their
    triangulation because refinement made them worse; ``cost_before/after``: the objective."""

    X: np.ndarray
    fallback: np.ndarray
    cost_before: float
    cost_after: float


def body_frame(X: np.ndarray) -> tuple[np.ndarray, float]:
    """Body frame of one pose. ``X: (J, 3)`` -> rotation ``(3, 3)`` whose columns are the
    body's x (right hip -> left hip), y and z (pelvis -> mid-shoulders) axes in the world,
    and the torso scale (mean hip-to-shoulder distance)."""
    pelvis = 0.5 * (X[LEFT_HIP] + X[RIGHT_HIP])
    neck = 0.5 * (X[LEFT_SHOULDER] + X[RIGHT_SHOULDER])
    x = X[LEFT_HIP] - X[RIGHT_HIP]
    z = neck - pelvis
    z = z / np.linalg.norm(z)
    x = x - (x @ z) * z
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    scale = 0.5 * (np.linalg.norm(X[LEFT_SHOULDER] - X[LEFT_HIP]) + np.linalg.norm(X[RIGHT_SHOULDER] - X[RIGHT_HIP]))
    return np.stack([x, y, z], axis=1), float(scale)


def _prior_block(X: np.ndarray, present: np.ndarray, prior) -> tuple[np.ndarray, np.ndarray] | None:
    """Linearized prior of one person: ``(G (K, 3n), h (K,))`` with residual ``G x - h`` for the
    ``n`` present joints' world coordinates ``x`` (joint-major), or None without hips/shoulders."""
    needed = [LEFT_HIP, RIGHT_HIP, LEFT_SHOULDER, RIGHT_SHOULDER]
    if not present[needed].all():
        return None
    rotation, scale = body_frame(X)
    if not np.isfinite(rotation).all() or not scale > 0:
        return None
    joints = np.flatnonzero(present)
    n = len(joints)
    # y_j = R^T (X_j - (X_lh + X_rh) / 2) / s  ->  y = B x with B = C ⊗ (R^T / s)
    C = np.eye(n)
    C[:, np.searchsorted(joints, LEFT_HIP)] -= 0.5
    C[:, np.searchsorted(joints, RIGHT_HIP)] -= 0.5
    B = np.kron(C, rotation.T / scale)
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

    def unpack(x):
        X = np.full((Pn, J, 3), np.nan)
        X[present] = x.reshape(-1, 3)
        return X

    def reprojection(x):
        pts = x.reshape(-1, 3)[obs_param]
        uv, depth = project(pts, obs_P)
        return uv - obs_xy, depth

    def objective(x, weights, blocks):
        e, _ = reprojection(x)
        sq = (e**2).sum(-1)
        f2 = robust_scale_px**2
        total = (obs_c * 2 * f2 * (np.sqrt(1 + sq / f2) - 1)).sum()
        for p, block in blocks.items():
            if block is not None:
                G, h = block
                r = G @ x[3 * param_of[p][present[p]].repeat(3) + np.tile(np.arange(3), present[p].sum())] - h
                total += prior_weight * 0.5 * (r @ r)
        return float(total)

    x = X0[present].reshape(-1).copy()
    blocks: dict[int, tuple | None] = {}
    if prior is not None and prior_weight > 0:
        blocks = {p: _prior_block(X0[p], present[p], prior) for p in range(Pn)}
    cost_before = objective(x, None, blocks)

    for _ in range(outer_iterations):
        e, _ = reprojection(x)
        sq = (e**2).sum(-1)
        robust_w = 1.0 / np.sqrt(1.0 + sq / robust_scale_px**2)           # ρ'(e²) of soft-L1
        sqrt_w = np.repeat(np.sqrt(2.0 * robust_w * obs_c), 2)             # (2K,)
        Xc = unpack(x)
        if prior is not None and prior_weight > 0:
            blocks = {p: _prior_block(Xc[p], present[p], prior) for p in range(Pn)}
        prior_rows, prior_cols, prior_vals, prior_h = [], [], [], []
        offset = 2 * K
        for p, block in blocks.items():
            if block is None:
                continue
            G, h = block
            cols = 3 * np.repeat(param_of[p][present[p]], 3) + np.tile(np.arange(3), present[p].sum())
            r_idx = offset + np.arange(G.shape[0])
            prior_rows.append(np.repeat(r_idx, len(cols)))
            prior_cols.append(np.tile(cols, G.shape[0]))
            prior_vals.append(np.sqrt(prior_weight) * G.reshape(-1))
            prior_h.append((cols, np.sqrt(prior_weight) * G, np.sqrt(prior_weight) * h))
            offset += G.shape[0]
        rows = np.concatenate([rows_reproj] + prior_rows)
        cols = np.concatenate([cols_reproj] + prior_cols)
        prior_vals_all = np.concatenate(prior_vals) if prior_vals else np.zeros(0)
        n_rows = offset

        def residuals(x):
            e, _ = reprojection(x)
            parts = [sqrt_w * e.reshape(-1)]
            parts += [G @ x[cols_p] - h for cols_p, G, h in prior_h]
            return np.concatenate(parts)

        def jacobian(x):
            pts = x.reshape(-1, 3)[obs_param]
            homogeneous = np.concatenate([pts, np.ones((K, 1))], axis=1)
            proj = np.einsum("kab,kb->ka", obs_P, homogeneous)
            z = proj[:, 2:3]
            uv = proj[:, :2] / z
            d = (obs_P[:, :2, :3] - uv[:, :, None] * obs_P[:, 2:3, :3]) / z[:, :, None]   # (K, 2, 3)
            vals = (d * sqrt_w.reshape(K, 2)[:, :, None]).reshape(-1)
            return sp.csr_matrix((np.concatenate([vals, prior_vals_all]), (rows, cols)),
                                 shape=(n_rows, n_params))

        solution = least_squares(residuals, x, jac=jacobian, method="trf", tr_solver="lsmr",
                                 x_scale="jac", max_nfev=max_iterations)
        x = solution.x

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
    return RefineResult(X, fallback, cost_before, objective(x_final, None, blocks))
