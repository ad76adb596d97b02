"""Refinement of triangulated poses (the paper's Eq. bundle):

    min_X  Σ_u ρ(‖π_u(X) − x_u‖²) · c_u  +  λ · E_P(X)  [+ Σ_b w ((|X_a − X_b| − L_b) / L_b)²],
    E_P(X) = −log Σ_l w_l N(X̃ | μ_l, Σ_l)

with ρ the soft-L1 robust loss of scale ``f`` pixels, ``c_u`` the keypoint confidences, X̃
the root-relative, scale-normalized pose in its own body frame (:mod:`mvm.core.prior`), λ the
prior weight and the optional soft bone-length terms of a rigid skeleton (:class:`BoneTerms`).

Outer iterations re-linearize what the inner problem holds fixed: the robust weights
(iteratively reweighted least squares for ρ), the body frame and scale of the
canonicalization, and the mixture component (the max-mixture approximation of E_P, whose
negative log-likelihood of one component is a sum of squares). The inner problem is then a
nonlinear least-squares problem per person (:func:`residuals`, pure functions of the joints):
its unknowns are the person's present joints (at most 17 × 3); each reprojection row touches
one joint, the linearized prior rows only that person and each bone row two of its joints.
In a person's body basis the prior's rows are a matrix shared by every person of the same
(present joints, component) group (:class:`mvm.core.linearized_prior.LinearPrior`), so its
dense share of the normal equations is one matrix per group, never built per person. Persons
are independent, so the Gauss-Newton normal equations are one dense ``3J × 3J`` system per
person, padded (absent joints: identity rows, they stay NaN) and assembled for all persons at
once from the group's matrix and ``3 × 3`` blocks (:func:`normal_equations`,
:func:`damped_steps`). The batched Levenberg-Marquardt of :mod:`mvm.core.lm` solves them
together, every person on its own damping and tolerance, stopping as soon as a bound on what
any step could still gain (:func:`model_decrease_bound`) falls under it. Where the time goes
is the damped ``3J × 3J`` solves, so a step solves only the persons still active.
"""
from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from mvm.core.geometry import project
from mvm.core.keypoints import BONES
from mvm.core.linearized_prior import LinearPrior, linearized_prior, prior_energy
from mvm.core.lm import levenberg_marquardt, spd_solve
from mvm.core.quality import row_nanmedian

log = logging.getLogger(__name__)

_BONES = np.array(BONES)
#: ``(B, J)`` bone incidence: +1 at a bone's first joint, -1 at its second.
_INCIDENCE = np.zeros((len(BONES), 17))
_INCIDENCE[np.arange(len(BONES)), _BONES[:, 0]] = 1.0
_INCIDENCE[np.arange(len(BONES)), _BONES[:, 1]] = -1.0
#: The inner solves of the outer iterations before the last stop at this multiple of the
#: tolerance: their robust weights, body frames and components are replaced anyway.
EARLY_TOLERANCE_FACTOR = 30.0


@dataclass
class RefineResult:
    """``X: (P, J, 3)`` refined poses; ``fallback: (P,)`` bool, persons kept at their
    triangulation because refinement made them worse; ``cost_before/after``: the objective.

    ``cost_after`` is evaluated when first read (by ``objective_after``): it takes a
    re-linearization of the prior that reconstruction never needs."""

    X: np.ndarray
    fallback: np.ndarray
    cost_before: float
    objective_after: Callable[[], float] = field(repr=False, compare=False)

    @functools.cached_property
    def cost_after(self) -> float:
        return float(self.objective_after())


@dataclass(frozen=True)
class Observations:
    """The 2D keypoints the refinement fits, in the persons' view-slot layout.

    ``xy: (P, M, J, 2)`` pixels; ``P: (P, M, 3, 4)`` the slots' projections; ``conf: (P, M, J)``
    confidences; ``fit: (P, M, J)`` bool, the keypoints fitted (inliers of present joints);
    ``products: (P, M, 4, 9)`` the four ``3 × 3`` matrices of every view that
    :meth:`normal_terms` combines (:meth:`build` computes them)."""

    xy: np.ndarray
    P: np.ndarray
    conf: np.ndarray
    fit: np.ndarray
    products: np.ndarray

    @staticmethod
    def build(xy: np.ndarray, P: np.ndarray, conf: np.ndarray, fit: np.ndarray) -> Observations:
        """With ``A`` the rows of a view's ``P[:, :3]``: ``A_uᵀA_u + A_vᵀA_v``, ``A_uᵀa_z + a_zᵀA_u``,
        ``A_vᵀa_z + a_zᵀA_v`` and ``a_zᵀa_z``."""
        A = P[..., :3]                                                                 # (P, M, 3, 3)
        cross = A[:, :, :2, :, None] * A[:, :, 2, None, None, :]                       # (P, M, 2, 3, 3)
        products = np.stack([np.einsum("pmia,pmib->pmab", A[:, :, :2], A[:, :, :2]),
                             cross[:, :, 0] + np.swapaxes(cross[:, :, 0], -1, -2),
                             cross[:, :, 1] + np.swapaxes(cross[:, :, 1], -1, -2),
                             A[:, :, 2, :, None] * A[:, :, 2, None, :]], axis=2)
        return Observations(xy, P, conf, fit, products.reshape(*P.shape[:2], 4, 9))

    def take(self, persons: np.ndarray) -> Observations:
        """The observations of ``persons: (Q,)`` indices."""
        return Observations(self.xy[persons], self.P[persons], self.conf[persons], self.fit[persons],
                            self.products[persons])

    def _homogeneous(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Image coordinates ``(P, M, 2, J)`` and depths ``(P, M, J)`` of the joints
        ``X: (P, J, 3)`` in every slot's view (:func:`mvm.core.geometry.project`); 0 and 1
        where not fitted."""
        uv, z = project(X[:, None], self.P)                                            # (P, M, J, 2)
        out = np.zeros(z.shape[:2] + (2, z.shape[2]))                   # C order: normal_terms' layout
        np.copyto(out, np.swapaxes(uv, 2, 3), where=self.fit[:, :, None])
        return out, np.where(self.fit, z, 1.0)

    def reprojection(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residual pixels ``(P, M, J, 2)`` and depths ``(P, M, J)`` of the keypoints at joints
        ``X: (P, J, 3)``; 0 and 1 where a keypoint is not fitted."""
        uv, depth = self._homogeneous(X)
        return np.where(self.fit[..., None], np.swapaxes(uv, 2, 3) - self.xy, 0.0), depth

    def normal_terms(self, X: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The reprojection rows' share of the normal equations at ``X: (P, J, 3)`` with
        weights ``w: (P, M, J)`` (0 where not fitted): the cost ``½ Σ w |e|²: (P,)``, the
        gradient ``(P, J, 3)`` and one ``3 × 3`` block ``Σ w DᵀD`` per joint ``(P, J, 3, 3)``.

        With ``A`` the rows of a view's ``P[:, :3]``, ``(u, v, 1) z`` the projection and ``e``
        its residual, ``D = (A_uv − (u, v)ᵀ a_z) / z``; ``DᵀD`` expands into the view's
        :attr:`products`, contracted with per-keypoint coefficients (no per-keypoint Jacobian
        is formed)."""
        Pn, M = self.P.shape[:2]
        uv, z = self._homogeneous(X)                                                   # (P, M, 2, J)
        e = np.where(self.fit[:, :, None], uv - np.swapaxes(self.xy, 2, 3), 0.0)
        hess, jac = np.empty((Pn, M, 4, X.shape[1])), np.empty((Pn, M, 3, X.shape[1]))   # coefficients
        c, g = hess[:, :, 0], jac[:, :, :2]
        np.divide(w, z**2, out=c)
        np.multiply(-c[:, :, None], uv, out=hess[:, :, 1:3])
        np.multiply(c, (uv**2).sum(2), out=hess[:, :, 3])
        np.multiply((w / z)[:, :, None], e, out=g)
        np.negative((g * uv).sum(2), out=jac[:, :, 2])
        blocks = np.matmul(np.swapaxes(hess.reshape(Pn, 4 * M, -1), 1, 2), self.products.reshape(Pn, 4 * M, 9))
        grad = np.matmul(np.swapaxes(jac.reshape(Pn, 3 * M, -1), 1, 2), self.P[..., :3].reshape(Pn, 3 * M, 3))
        return 0.5 * (w * (e**2).sum(2)).sum((1, 2)), grad, blocks.reshape(Pn, -1, 3, 3)


@dataclass(frozen=True)
class BoneTerms:
    """Soft bone-length terms ``√w (|X_a − X_b| − L) / L`` (a relative error, weight ``w`` in
    pixels²) of the :data:`mvm.core.keypoints.BONES` ``(a, b)``. ``target: (P, B)`` lengths
    ``L``, 0 where a person's bone has no term."""

    target: np.ndarray
    root_weight: float

    @staticmethod
    def build(lengths, weight: float, present: np.ndarray) -> BoneTerms:
        """Terms for the bones of ``lengths: (P, B)`` (NaN: none) whose two joints are present
        (``present: (P, J)`` bool)."""
        target = np.asarray(lengths, dtype=float).reshape(len(present), len(_BONES))
        ok = present[:, _BONES[:, 0]] & present[:, _BONES[:, 1]] & np.isfinite(target) & (target > 0)
        return BoneTerms(np.where(ok, target, 0.0), float(np.sqrt(weight)))

    def take(self, persons: np.ndarray) -> BoneTerms:
        return BoneTerms(self.target[persons], self.root_weight)

    def linearize(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residuals ``(P, B)`` at ``X: (P, J, 3)`` and their derivatives ``u: (P, B, 3)`` by
        the coordinates of each bone's first joint (``−u`` by its second); 0 without a term."""
        d = X[:, _BONES[:, 0]] - X[:, _BONES[:, 1]]
        length = np.linalg.norm(d, axis=-1)
        on = self.target > 0
        scale = np.where(on, self.root_weight / np.where(on, self.target, 1.0), 0.0)
        u = d * (scale / np.maximum(length, 1e-12))[..., None]
        return scale * (length - self.target), u


@dataclass(frozen=True)
class InnerProblem:
    """The least-squares problem of one outer iteration, for ``P`` persons: the observations,
    the IRLS root weights ``sqrt_w: (P, M, J)`` of their reprojection residuals, the
    linearized prior and the bone terms (or None)."""

    obs: Observations
    sqrt_w: np.ndarray
    prior: LinearPrior
    bones: BoneTerms | None

    def take(self, persons: np.ndarray) -> InnerProblem:
        return InnerProblem(self.obs.take(persons), self.sqrt_w[persons], self.prior.take(persons),
                            None if self.bones is None else self.bones.take(persons))

    def normal_equations(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:func:`normal_equations` at ``x: (P, 3J)`` (the solver's interface,
        :class:`mvm.core.lm.BatchedLeastSquares`)."""
        return normal_equations(x, self)

    def damped_steps(self, blocks: np.ndarray, grad: np.ndarray, damping: np.ndarray) -> np.ndarray:
        """:func:`damped_steps` of these persons (the solver's interface)."""
        return damped_steps(self.prior, blocks, grad, damping)


def residuals(x: np.ndarray, problem: InnerProblem) -> np.ndarray:
    """Every person's residuals at ``x: (P, 3J)``: ``(P, 2 M J + 3J [+ B])``, the weighted
    reprojection errors, the linearized prior rows and the bone rows. The inner cost is half
    their sum of squares per person."""
    X = x.reshape(len(x), -1, 3)
    e, _ = problem.obs.reprojection(X)
    rows = [(problem.sqrt_w[..., None] * e).reshape(len(x), -1), problem.prior.residuals(x)]
    if problem.bones is not None:
        rows.append(problem.bones.linearize(X)[0])
    return np.concatenate(rows, axis=1)


def normal_equations(x: np.ndarray, problem: InnerProblem
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The Gauss-Newton normal equations of :func:`residuals` ``r`` with Jacobian ``Jr`` at
    ``x: (P, 3J)``: the cost ``½|r|²: (P,)``, the gradient ``Jrᵀ r: (P, 3J)``, the ``3 × 3``
    blocks ``(P, K, 3, 3)`` that ``Jrᵀ Jr`` adds to the prior's constant share
    (:meth:`LinearPrior.gram`, :func:`hessian`): the ``J`` diagonal blocks (a joint's keypoints
    and bones), then with bone terms the ``(a, b)`` blocks of the
    :data:`~mvm.core.keypoints.BONES` and their ``(b, a)``; and ``reach: (P,)``, a bound on the
    decrease any step can bring the Gauss-Newton model (:func:`model_decrease_bound`)."""
    Pn, J = len(x), x.shape[1] // 3
    X = x.reshape(Pn, J, 3)
    cost, grad, blocks = problem.obs.normal_terms(X, problem.sqrt_w**2)
    energy, prior_grad = problem.prior.energy_gradient(x)
    cost += energy
    grad = grad.reshape(Pn, -1) + prior_grad
    if problem.bones is not None:
        r_bone, u = problem.bones.linearize(X)
        cost += 0.5 * (r_bone**2).sum(1)
        grad += np.matmul(_INCIDENCE.T, r_bone[..., None] * u).reshape(Pn, -1)
    reach = model_decrease_bound(blocks, grad.reshape(Pn, J, 3))
    if problem.bones is None:
        return cost, grad, blocks, reach
    uu = (u[..., :, None] * u[..., None, :]).reshape(Pn, -1, 9)                       # (P, B, 9)
    blocks += np.matmul(np.abs(_INCIDENCE.T), uu).reshape(Pn, J, 3, 3)
    return cost, grad, np.concatenate([blocks, -uu.reshape(Pn, -1, 3, 3), -uu.reshape(Pn, -1, 3, 3)], axis=1), reach


def model_decrease_bound(D: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``½ Σ_j g_jᵀ D_j⁻¹ g_j: (P,)`` for the reprojection rows' diagonal blocks ``D: (P, J, 3, 3)``
    and the gradient ``g: (P, J, 3)``: a bound on ``½ gᵀ H⁻¹ g``, the most any step can lower
    the Gauss-Newton model ``H``, since ``H`` is ``D`` plus positive semidefinite terms (the
    prior's and the bones'). Infinite where a joint with a gradient has a singular block
    (seen in fewer than two views), 0 where nothing pulls."""
    V, g3 = D.reshape(-1, 9), g.reshape(-1, 3)                                   # rows of (P J,)
    # The adjugate of the symmetric block (D⁻¹ = adj / det), its six distinct entries at once:
    # with a, d, f / b, e / c the upper triangle, bc − e², ac − f², ab − d², fe − dc, df − ae, de − bf.
    cof = V.take(_COFACTOR[0], 1) * V.take(_COFACTOR[1], 1) - V.take(_COFACTOR[2], 1) * V.take(_COFACTOR[3], 1)
    det = V[:, 0] * cof[:, 0] + V[:, 1] * cof[:, 3] + V[:, 2] * cof[:, 5]
    quad = (cof * (g3.take(_PAIRS[0], 1) * g3.take(_PAIRS[1], 1))) @ _PAIR_WEIGHTS
    regular = det > 1e-12 * (V[:, 0] + V[:, 4] + V[:, 8]) ** 3
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.where(regular, quad / np.where(regular, det, 1.0), np.where(g3.any(1), np.inf, 0.0))
    return 0.5 * q.reshape(len(D), -1).sum(1)


#: Flat ``3 × 3`` indices of the products whose differences are the adjugate entries of
#: :func:`model_decrease_bound`, and the pairs of gradient coordinates (with their weights in
#: the quadratic form) that multiply them.
_COFACTOR = np.array([[4, 0, 0, 2, 1, 1], [8, 8, 4, 5, 2, 5], [5, 2, 1, 1, 0, 4], [5, 2, 1, 8, 5, 2]])
_PAIRS = np.array([[0, 1, 2, 0, 1, 0], [0, 1, 2, 1, 2, 2]])
_PAIR_WEIGHTS = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])


@functools.lru_cache(maxsize=8)
def block_entries(J: int, bones: bool) -> np.ndarray:
    """Flat indices into a ``3J × 3J`` matrix of the ``3 × 3`` blocks of
    :func:`normal_equations`: the ``J`` diagonal blocks, then ``(a, b)`` and ``(b, a)`` of every
    bone when ``bones``. ``(9 K,)`` for ``K`` blocks, row-major within each block (cached, read-only)."""
    rows, cols = np.arange(J), np.arange(J)
    if bones:
        rows = np.concatenate([rows, _BONES[:, 0], _BONES[:, 1]])
        cols = np.concatenate([cols, _BONES[:, 1], _BONES[:, 0]])
    x, y = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    entries = ((3 * rows[:, None, None] + x) * 3 * J + 3 * cols[:, None, None] + y).reshape(-1)
    entries.setflags(write=False)
    return entries


def hessian(GtG: np.ndarray, blocks: np.ndarray, copy: bool = True) -> np.ndarray:
    """``Jrᵀ Jr: (P, 3J, 3J)`` from the prior's ``GtG: (P, 3J, 3J)`` (:meth:`LinearPrior.gram`)
    and the ``blocks: (P, K, 3, 3)`` of :func:`normal_equations` at :func:`block_entries`
    (added to ``GtG`` itself unless ``copy``); the same in a body basis with both rotated."""
    Pn, n, _ = GtG.shape
    H = GtG.copy() if copy else GtG
    H.reshape(Pn, -1)[:, block_entries(n // 3, blocks.shape[1] > n // 3)] += blocks.reshape(Pn, -1)
    return H


def damped_steps(prior: LinearPrior, blocks: np.ndarray, grad: np.ndarray, damping: np.ndarray) -> np.ndarray:
    """Levenberg-Marquardt steps ``(P, 3J)``: ``(H + μ diag(H)) δ = −grad`` with ``H`` the
    prior's share plus ``blocks: (P, K, 3, 3)`` of :func:`normal_equations`, ``grad: (P, 3J)``,
    ``damping μ: (P,)``. Solved in each person's body basis (:class:`LinearPrior`), where the
    prior's share is its group's matrix: the ``3 × 3`` blocks are rotated instead of the whole
    matrix, and the damping scales that basis's diagonal. A coordinate that no residual depends
    on (a zero diagonal: an absent joint) gets an identity row and does not move."""
    Pn, n = grad.shape
    K = blocks.shape[1]
    R, s2 = prior.rotation, prior.scale**2 / prior.weight
    # R B Rᵀ of every (symmetric) block, times s² / λ (the whole system is scaled by s² / λ, so
    # the prior's share is its group's matrix as it is): two products per person, not per block.
    Rt = np.swapaxes(R, 1, 2) * s2[:, None, None]
    rotated = np.matmul(blocks.reshape(Pn, 3 * K, 3), Rt).reshape(Pn, K, 3, 3)
    rotated = np.matmul(np.swapaxes(rotated, 2, 3).reshape(Pn, 3 * K, 3), np.swapaxes(R, 1, 2)).reshape(Pn, K, 3, 3)
    H = hessian(np.take(prior.gram_body, prior.which, axis=0), rotated, copy=False)
    diagonal = H.reshape(Pn, -1)[:, :: n + 1]
    diagonal[:] = np.where(diagonal > 0, diagonal * (1.0 + damping[:, None]), 1.0)
    step = spd_solve(H, prior.to_body(grad) * s2[:, None])
    return -prior.to_world(step)


def robust_terms(e: np.ndarray, obs: Observations, robust_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The soft-L1 reprojection terms of residuals ``e: (P, M, J, 2)`` (:meth:`Observations.reprojection`):
    ``Σ c ρ(e²): (P,)`` per person and the IRLS root weights ``sqrt(2 ρ'(e²) c): (P, M, J)``
    (0 where not fitted), each keypoint's ``c`` its confidence squared, as the triangulation
    weighs it (:func:`mvm.core.geometry.weighted_dlt`: the confidence on each row)."""
    f2 = robust_scale**2
    root = np.sqrt(1.0 + (e[..., 0] ** 2 + e[..., 1] ** 2) / f2)
    c = np.where(obs.fit, obs.conf**2, 0.0)
    return (c * 2 * f2 * (root - 1)).sum((1, 2)), np.sqrt(2.0 * c / root)


def _bone_cost(bones: BoneTerms | None, X: np.ndarray) -> float:
    return 0.0 if bones is None else 0.5 * float(np.sum(bones.linearize(X)[0] ** 2))


def fallback_persons(e0: np.ndarray, e1: np.ndarray, depth1: np.ndarray, X: np.ndarray, present: np.ndarray,
                     obs: Observations, robust_scale: float) -> np.ndarray:
    """``(P,)`` bool: observed persons whose refinement ``X: (P, J, 3)`` is not finite, has a
    median reprojection error above twice the triangulation's plus ``robust_scale``, or
    puts a fitted joint behind a camera. ``e0, e1: (P, M, J, 2)`` the reprojection residuals of
    the triangulation and of the refinement, ``depth1: (P, M, J)`` the refinement's depths."""
    observed = obs.fit.any((1, 2))
    finite = np.where(present[..., None], np.isfinite(X), True).all((1, 2))

    def median_error(e):
        return row_nanmedian(np.where(obs.fit, np.linalg.norm(e, axis=-1), np.nan).reshape(len(X), -1))

    with np.errstate(all="ignore"):
        worse = median_error(e1) > 2.0 * median_error(e0) + robust_scale
        behind = ~(depth1 > 0).all((1, 2))
    return observed & (~finite | worse | behind)


def refine_poses(X0: np.ndarray, xy: np.ndarray, conf: np.ndarray, P: np.ndarray, inliers: np.ndarray,
                 prior=None, prior_weight: float | np.ndarray = 10.0, robust_scale: float = 5.0,
                 max_iterations: int = 30, outer_iterations: int = 3,
                 bone_lengths: np.ndarray | None = None, bone_weight: float = 0.0,
                 tolerance: float = 1e-8) -> RefineResult:
    """Refine ``P`` persons' 3D joints.

    Args:
        X0: ``(P, J, 3)`` joints (NaN stays NaN); xy, conf: ``(P, M, J, 2)`` keypoints, ``(P, M, J)``.
        P: ``(P, M, 3, 4)`` projection matrices of the views.
        inliers: ``(P, M, J)`` bool, the keypoints to fit.
        prior: a :class:`mvm.core.prior.PosePrior` or None (reprojection only).
        prior_weight: λ, image units² per nat, one or each person's ``(P,)``; robust_scale: scale ``f``
            of the soft-L1 loss, in image units (those of ``xy``: pixels, or person sizes).
        max_iterations: Levenberg-Marquardt steps per person and outer iteration.
        outer_iterations: re-linearizations of the robust loss and the prior.
        bone_lengths: ``(P, B)`` target lengths of :data:`mvm.core.keypoints.BONES` (NaN: none);
            ``bone_weight``: image units² per squared relative length error (0: no bone term).
        tolerance: relative change of cost and joints at which a person's inner solve stops
            (:func:`mvm.core.lm.levenberg_marquardt`) in the last outer iteration; the earlier
            ones stop at :data:`EARLY_TOLERANCE_FACTOR` times it.
    Returns :class:`RefineResult`.

    Persons are independent: they are refined a few at a time (:data:`REFINE_CHUNK`), with
    the result of all at once (up to rounding).
    """
    X0 = np.asarray(X0, dtype=float)
    Pn, J, _ = X0.shape
    step = max(1, REFINE_CHUNK // max(np.shape(inliers)[1] * J, 1))
    weights = np.broadcast_to(np.asarray(prior_weight, dtype=float), (Pn,))
    parts = [_refine_persons(X0[r], xy[r], conf[r], P[r], inliers[r], prior, weights[r], robust_scale, max_iterations,
                             outer_iterations, None if bone_lengths is None else np.asarray(bone_lengths)[r],
                             bone_weight, tolerance)
             for r in (slice(s, s + step) for s in range(0, max(Pn, 1), step))]
    fallback = np.concatenate([part.fallback for part in parts])
    if fallback.any():
        log.warning("refinement diverged for %d person(s); kept their triangulation", int(fallback.sum()))
    if len(parts) == 1:
        return parts[0]
    return RefineResult(np.concatenate([part.X for part in parts]), fallback,
                        sum(part.cost_before for part in parts),
                        lambda: sum(part.objective_after() for part in parts))


#: Person · view slot · joint entries refined at once: the normal equations' coefficients stay
#: a few MB whatever the length of the video (see :data:`mvm.core.pose_distance.PAIRS_CHUNK`).
REFINE_CHUNK = 2**16


def _refine_persons(X0: np.ndarray, xy: np.ndarray, conf: np.ndarray, P: np.ndarray, inliers: np.ndarray, prior,
                    prior_weight: np.ndarray, robust_scale: float, max_iterations: int, outer_iterations: int,
                    bone_lengths: np.ndarray | None, bone_weight: float, tolerance: float) -> RefineResult:
    """:func:`refine_poses` of a few persons, arguments as its own."""
    Pn, J, _ = X0.shape
    present = np.isfinite(X0).all(-1)                                    # (P, J)
    obs = Observations.build(np.asarray(xy, dtype=float), np.asarray(P, dtype=float), np.asarray(conf, dtype=float),
                       np.asarray(inliers, bool) & present[:, None, :])
    if not obs.fit.any():
        return RefineResult(X0.copy(), np.zeros(Pn, bool), 0.0, lambda: 0.0)
    bones = (BoneTerms.build(bone_lengths, bone_weight, present)
             if bone_lengths is not None and bone_weight > 0 else None)
    prior = prior if prior is not None and np.any(np.asarray(prior_weight) > 0) else None
    X = np.where(present[..., None], X0, 0.0)
    e0, _ = obs.reprojection(X)
    robust, sqrt_w = robust_terms(e0, obs, robust_scale)
    linear = linearized_prior(X, present, prior, prior_weight)
    cost_before = float(robust.sum() + linear.energy(X.reshape(Pn, -1)).sum()) + _bone_cost(bones, X)
    for k in range(outer_iterations):
        if k:
            linear = linearized_prior(X, present, prior, prior_weight)
            sqrt_w = robust_terms(obs.reprojection(X)[0], obs, robust_scale)[1]
        problem = InnerProblem(obs, sqrt_w, linear, bones)
        inner_tolerance = tolerance if k == outer_iterations - 1 else EARLY_TOLERANCE_FACTOR * tolerance
        X = levenberg_marquardt(X.reshape(Pn, -1), problem, max_iterations, inner_tolerance).reshape(Pn, J, 3)
    X = np.where(present[..., None], X, np.nan)
    with np.errstate(all="ignore"):
        e1, depth1 = obs.reprojection(np.where(present[..., None], X, 0.0))
    fallback = fallback_persons(e0, e1, depth1, X, present, obs, robust_scale)
    X[fallback] = X0[fallback]
    X_fit, e_fit = np.where(present[..., None], X, 0.0), np.where(fallback[:, None, None, None], e0, e1)

    def objective_after() -> float:                      # of copies: the caller may change X
        robust, _ = robust_terms(e_fit, obs, robust_scale)
        return (float(robust.sum() + prior_energy(X_fit, present, prior, prior_weight).sum())
                + _bone_cost(bones, X_fit))

    return RefineResult(X, fallback, cost_before, objective_after)
