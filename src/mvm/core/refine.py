"""Refinement of triangulated poses (the paper's Eq. bundle):

    min_X  Σ_u ρ(‖π_u(X) − x_u‖²) · c_u  +  λ · E_P(X),   E_P(X) = −log Σ_l w_l N(X̃ | μ_l, Σ_l)

with ρ the soft-L1 robust loss of scale ``f`` pixels, ``c_u`` the keypoint confidences, X̃
the root-relative, scale-normalized pose in its own body frame (:mod:`mvm.core.prior`) and λ the
prior weight. It is solved with ``scipy.optimize.least_squares`` (trust region, LSMR) on an
analytic sparse Jacobian whose pattern is built once per outer iteration
(residuals and Jacobian are pure functions of the parameter vector):

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

from mvm.core.geometry import project
from mvm.core.keypoints import BONES, LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER
from mvm.core.prior import body_frame, canonicalize

log = logging.getLogger(__name__)


@dataclass
class RefineResult:
    """``X: (P, J, 3)`` refined poses; ``fallback: (P,)`` bool, persons kept at their
    triangulation because refinement made them worse; ``cost_before/after``: the objective."""

    X: np.ndarray
    fallback: np.ndarray
    cost_before: float
    cost_after: float


def _median_by(values: np.ndarray, group: np.ndarray, n: int) -> np.ndarray:
    """Median of ``values: (K,)`` within each of ``n`` groups (``group: (K,)`` int) -> ``(n,)``,
    NaN for empty groups (the mean of the two middle values for even counts, as np.median)."""
    order = np.lexsort((values, group))
    counts = np.bincount(group, minlength=n)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    low = starts + (counts - 1) // 2
    high = starts + counts // 2
    ok = counts > 0
    out = np.full(n, np.nan)
    sorted_values = values[order]
    out[ok] = 0.5 * (sorted_values[low[ok]] + sorted_values[high[ok]])
    return out


@dataclass
class PriorBlock:
    """The linearized prior of persons sharing the same present joints and mixture component:
    residuals ``G[p] @ x[cols[p]] - h[p]``.

    ``cols: (Pg, 3n)`` parameter columns of the persons' present joints (joint-major x, y, z);
    ``G: (Pg, K, 3n)``; ``h: (Pg, K)`` with ``K = 3n``."""

    cols: np.ndarray
    G: np.ndarray
    h: np.ndarray

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """``(Pg, K)``."""
        return np.einsum("pkc,pc->pk", self.G, x[self.cols]) - self.h


def prior_blocks(X: np.ndarray, present: np.ndarray, param_of: np.ndarray, prior,
                 weight: float) -> list[PriorBlock]:
    """Linearize ``weight · E_P`` at ``X: (P, J, 3)`` for every person that has both hips and
    shoulders: the prior's canonicalization ``y_j = R (X_j − pelvis) / s`` with the body frame
    ``R, s`` held fixed (so ``y`` is linear in ``X``) and the max-mixture component, whose
    negative log-likelihood is ``½ |W (y − μ)|²``. Persons are batched by (present joints,
    component): ``param_of: (P, J)`` parameter index of each present joint."""
    rotation, _, scale = body_frame(np.where(present[..., None], X, np.nan))      # (P, 3, 3), (P,)
    needed = [LEFT_HIP, RIGHT_HIP, LEFT_SHOULDER, RIGHT_SHOULDER]
    usable = present[:, needed].all(1) & np.isfinite(rotation).all((1, 2)) & (scale > 0)
    if not usable.any():
        return []
    canonical = canonicalize(np.where(present[..., None], X, np.nan))
    component = np.full(len(X), -1)
    component[usable] = prior.best_component(canonical[usable])
    usable &= component >= 0
    keys = np.concatenate([present, component[:, None]], axis=1)[usable]
    persons = np.flatnonzero(usable)
    _, group = np.unique(keys, axis=0, return_inverse=True)
    blocks = []
    for g in range(group.max() + 1):
        ps = persons[group.ravel() == g]
        joints = np.flatnonzero(present[ps[0]])
        n = len(joints)
        mean, W, _ = prior.whitening(present[ps[0]], int(component[ps[0]]))
        # W @ (C ⊗ R/s) with C = I − ½ (1 e_lh^T + 1 e_rh^T), the pelvis subtraction.
        Wr = W.reshape(len(W), n, 3)
        WC = Wr.copy()
        total = Wr.sum(axis=1)
        WC[:, np.searchsorted(joints, LEFT_HIP)] -= 0.5 * total
        WC[:, np.searchsorted(joints, RIGHT_HIP)] -= 0.5 * total
        G = np.einsum("kja,pab->pkjb", WC, rotation[ps] / scale[ps, None, None]).reshape(len(ps), len(W), 3 * n)
        cols = (3 * param_of[np.ix_(ps, joints)][..., None] + np.arange(3)).reshape(len(ps), 3 * n)
        root = np.sqrt(weight)
        blocks.append(PriorBlock(cols, root * G, root * np.broadcast_to(W @ mean, (len(ps), len(W))).copy()))
    return blocks


@dataclass(frozen=True)
class FittedKeypoints:
    """The ``K`` 2D keypoints the refinement fits, flattened.

    ``param: (K,)`` parameter joint (row of ``x.reshape(-1, 3)``) each keypoint observes;
    ``person: (K,)`` its person; ``P: (K, 3, 4)`` its view's projection; ``xy: (K, 2)`` pixels;
    ``conf: (K,)`` confidences."""

    param: np.ndarray
    person: np.ndarray
    P: np.ndarray
    xy: np.ndarray
    conf: np.ndarray


@dataclass(frozen=True)
class SparsityPattern:
    """The Jacobian's non-zero entries (``rows``, ``cols``: 3 per reprojection row, a dense
    block per person's prior rows), the constant prior values and the ``shape``."""

    rows: np.ndarray
    cols: np.ndarray
    prior_values: np.ndarray
    shape: tuple[int, int]


@dataclass(frozen=True)
class BoneTerms:
    """Soft bone-length terms ``√w (|X_a − X_b| − L) / L`` (a relative error, weight ``w`` in
    pixels²). ``ends: (N, 2)`` parameter joints of each bone; ``target: (N,)`` lengths ``L``."""

    ends: np.ndarray
    target: np.ndarray
    root_weight: float

    @staticmethod
    def build(lengths, weight: float, present: np.ndarray, param_of: np.ndarray) -> "BoneTerms":
        """Terms for the :data:`mvm.core.keypoints.BONES` of ``lengths: (P, B)`` (NaN: none)
        whose two joints are present."""
        bones = np.array(BONES)
        target = np.asarray(lengths, dtype=float).reshape(len(present), len(bones))
        ok = present[:, bones[:, 0]] & present[:, bones[:, 1]] & np.isfinite(target) & (target > 0)
        p, b = np.nonzero(ok)
        ends = np.stack([param_of[p, bones[b, 0]], param_of[p, bones[b, 1]]], axis=1)
        return BoneTerms(ends, target[p, b], float(np.sqrt(weight)))

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """``(N,)``."""
        points = x.reshape(-1, 3)
        length = np.linalg.norm(points[self.ends[:, 0]] - points[self.ends[:, 1]], axis=-1)
        return self.root_weight * (length - self.target) / self.target

    def jacobian_values(self, x: np.ndarray) -> np.ndarray:
        """``(N, 2, 3)``: derivatives by the coordinates of each bone's two joints."""
        points = x.reshape(-1, 3)
        d = points[self.ends[:, 0]] - points[self.ends[:, 1]]
        u = d / np.maximum(np.linalg.norm(d, axis=-1), 1e-12)[:, None] * (self.root_weight / self.target)[:, None]
        return np.stack([u, -u], axis=1)


def reprojection(x: np.ndarray, fitted: FittedKeypoints) -> tuple[np.ndarray, np.ndarray]:
    """Residual pixels ``(K, 2)`` and depths ``(K,)`` of the fitted keypoints at ``x: (3 n,)``."""
    uv, depth = project(x.reshape(-1, 3)[fitted.param], fitted.P)
    return uv - fitted.xy, depth


def objective(x: np.ndarray, fitted: FittedKeypoints, blocks: list[PriorBlock], robust_scale_px: float,
              bones: BoneTerms | None = None) -> float:
    """Σ c ρ(e²) + λ E_P (up to the mixture's constants) [+ the bone terms] at ``x: (3 n,)``."""
    e, _ = reprojection(x, fitted)
    f2 = robust_scale_px**2
    total = (fitted.conf * 2 * f2 * (np.sqrt(1 + (e**2).sum(-1) / f2) - 1)).sum()
    total += 0.5 * np.sum(bones.residuals(x) ** 2) if bones is not None else 0.0
    return float(total + sum(0.5 * np.sum(b.residuals(x) ** 2) for b in blocks))


def residuals(x: np.ndarray, fitted: FittedKeypoints, sqrt_w: np.ndarray, blocks: list[PriorBlock],
              pattern: SparsityPattern, bones: BoneTerms | None = None) -> np.ndarray:
    """The inner least-squares residuals ``(2 K + prior rows [+ bone rows],)``: weighted
    reprojection errors (``sqrt_w: (2 K,)``, the IRLS weights of ρ), the linearized prior rows
    and the bone terms."""
    e, _ = reprojection(x, fitted)
    extra = [bones.residuals(x)] if bones is not None else []
    return np.concatenate([sqrt_w * e.reshape(-1)] + [b.residuals(x).reshape(-1) for b in blocks] + extra)


def jacobian(x: np.ndarray, fitted: FittedKeypoints, sqrt_w: np.ndarray, blocks: list[PriorBlock],
             pattern: SparsityPattern, bones: BoneTerms | None = None) -> sp.csr_matrix:
    """The analytic Jacobian of :func:`residuals` at ``x``, sparse as ``pattern``."""
    K = len(fitted.param)
    homogeneous = np.concatenate([x.reshape(-1, 3)[fitted.param], np.ones((K, 1))], axis=1)
    proj = np.einsum("kab,kb->ka", fitted.P, homogeneous)
    z = proj[:, 2:3]
    uv = proj[:, :2] / z
    d = (fitted.P[:, :2, :3] - uv[:, :, None] * fitted.P[:, 2:3, :3]) / z[:, :, None]   # (K, 2, 3)
    values = (d * sqrt_w.reshape(K, 2)[:, :, None]).reshape(-1)
    extra = [bones.jacobian_values(x).reshape(-1)] if bones is not None else []
    return sp.csr_matrix((np.concatenate([values, pattern.prior_values] + extra), (pattern.rows, pattern.cols)),
                         shape=pattern.shape)


def sparsity_pattern(fitted: FittedKeypoints, blocks: list[PriorBlock], n_params: int,
                     bones: BoneTerms | None = None) -> SparsityPattern:
    """Where :func:`jacobian` is non-zero: 3 entries per reprojection row (the coordinates of the
    keypoint's joint), a dense block per person's prior rows, 6 per bone row (its two joints)."""
    K = len(fitted.param)
    rows_reproj = np.repeat(np.arange(2 * K), 3)
    cols_reproj = (3 * np.repeat(fitted.param, 2)[:, None] + np.arange(3)).reshape(-1)
    sizes = [b.G.shape[0] * b.G.shape[1] for b in blocks]
    starts = 2 * K + np.cumsum([0] + sizes)
    rows = np.concatenate([rows_reproj] + [np.repeat(np.arange(a, a + n), b.G.shape[2])
                                           for a, n, b in zip(starts, sizes, blocks)])
    cols = np.concatenate([cols_reproj] + [np.broadcast_to(b.cols[:, None, :], b.G.shape).reshape(-1)
                                           for b in blocks])
    prior_values = np.concatenate([np.zeros(0)] + [b.G.reshape(-1) for b in blocks])
    n_rows = int(starts[-1])
    if bones is not None:
        rows = np.concatenate([rows, n_rows + np.repeat(np.arange(len(bones.target)), 6)])
        cols = np.concatenate([cols, (3 * bones.ends[:, :, None] + np.arange(3)).reshape(-1)])
        n_rows += len(bones.target)
    return SparsityPattern(rows, cols, prior_values, (n_rows, n_params))


def irls_weights(x: np.ndarray, fitted: FittedKeypoints, robust_scale_px: float) -> np.ndarray:
    """``sqrt(2 ρ'(e²) c)`` of soft-L1 at ``x``, repeated for the two rows of each keypoint: ``(2 K,)``."""
    e, _ = reprojection(x, fitted)
    robust_w = 1.0 / np.sqrt(1.0 + (e**2).sum(-1) / robust_scale_px**2)
    return np.repeat(np.sqrt(2.0 * robust_w * fitted.conf), 2)


def fallback_persons(X0: np.ndarray, X: np.ndarray, present: np.ndarray, fitted: FittedKeypoints,
                     robust_scale_px: float) -> np.ndarray:
    """``(P,)`` bool: observed persons whose refinement is not finite, has a median
    reprojection error above twice the triangulation's plus ``robust_scale_px``, or puts a
    fitted joint behind a camera."""
    Pn = len(X0)
    e0, _ = reprojection(X0[present].reshape(-1), fitted)
    e1, depth1 = reprojection(X[present].reshape(-1), fitted)
    observed = np.bincount(fitted.person, minlength=Pn) > 0
    finite = np.where(present[..., None], np.isfinite(X), True).all((1, 2))
    worse = (_median_by(np.linalg.norm(e1, axis=-1), fitted.person, Pn)
             > 2.0 * _median_by(np.linalg.norm(e0, axis=-1), fitted.person, Pn) + robust_scale_px)
    behind = np.bincount(fitted.person, weights=depth1 <= 0, minlength=Pn) > 0
    return observed & (~finite | worse | behind)


def refine_poses(X0: np.ndarray, xy: np.ndarray, conf: np.ndarray, P: np.ndarray, inliers: np.ndarray,
                 prior=None, prior_weight: float = 10.0, robust_scale_px: float = 5.0,
                 max_iterations: int = 30, outer_iterations: int = 3,
                 bone_lengths: np.ndarray | None = None, bone_weight: float = 0.0,
                 tolerance: float = 1e-8) -> RefineResult:
    """Refine ``P`` persons' 3D joints.

    Args:
        X0: ``(P, J, 3)`` joints (NaN stays NaN); xy, conf: ``(P, M, J, 2)`` keypoints, ``(P, M, J)``.
        P: ``(P, M, 3, 4)`` projection matrices of the views.
        inliers: ``(P, M, J)`` bool, the keypoints to fit.
        prior: a :class:`mvm.core.prior.PosePrior` or None (reprojection only).
        prior_weight: λ, pixels² per nat; robust_scale_px: scale ``f`` of the soft-L1 loss.
        bone_lengths: ``(P, B)`` lengths of :data:`mvm.core.keypoints.BONES` each person's bones
            are pulled to (NaN: none), e.g. its track's; ``bone_weight``: pixels² per squared
            relative length error (0: no bone term).
        tolerance: relative change of the cost and of the parameters at which an inner solve
            stops (``ftol``, ``xtol`` of ``scipy.optimize.least_squares``).
    Returns :class:`RefineResult`.
    """
    X0 = np.asarray(X0, dtype=float)
    Pn, J, _ = X0.shape
    present = np.isfinite(X0).all(-1)                                    # (P, J)
    param_of = -np.ones((Pn, J), dtype=int)
    param_of[present] = np.arange(present.sum())
    n_params = 3 * int(present.sum())
    p_idx, m_idx, j_idx = np.nonzero(inliers & present[:, None, :])
    if n_params == 0 or len(p_idx) == 0:
        return RefineResult(X0.copy(), np.zeros(Pn, bool), 0.0, 0.0)
    fitted = FittedKeypoints(param_of[p_idx, j_idx], p_idx, P[p_idx, m_idx], xy[p_idx, m_idx, j_idx],
                             conf[p_idx, m_idx, j_idx])
    use_prior = prior is not None and prior_weight > 0

    def unpack(x):
        X = np.full((Pn, J, 3), np.nan)
        X[present] = x.reshape(-1, 3)
        return X

    def linearized_prior(X):
        return prior_blocks(X, present, param_of, prior, prior_weight) if use_prior else []

    bones = (BoneTerms.build(bone_lengths, bone_weight, present, param_of)
             if bone_lengths is not None and bone_weight > 0 else None)
    x = X0[present].reshape(-1).copy()
    cost_before = objective(x, fitted, linearized_prior(X0), robust_scale_px, bones)
    for _ in range(outer_iterations):
        sqrt_w = irls_weights(x, fitted, robust_scale_px)
        blocks = linearized_prior(unpack(x))
        pattern = sparsity_pattern(fitted, blocks, n_params, bones)
        x = least_squares(residuals, x, jac=jacobian, method="trf", tr_solver="lsmr", x_scale="jac",
                          max_nfev=max_iterations, ftol=tolerance, xtol=tolerance,
                          args=(fitted, sqrt_w, blocks, pattern, bones)).x

    X = unpack(x)
    fallback = fallback_persons(X0, X, present, fitted, robust_scale_px)
    X[fallback] = X0[fallback]
    if fallback.any():
        log.warning("refinement diverged for %d person(s); kept their triangulation", int(fallback.sum()))
    cost_after = objective(X[present].reshape(-1), fitted, linearized_prior(X), robust_scale_px, bones)
    return RefineResult(X, fallback, cost_before, cost_after)
