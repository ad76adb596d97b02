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
one joint, the linearized prior rows only that person (a constant dense ``GᵀG`` per outer
iteration) and each bone row two of its joints. Persons are independent, so the Gauss-Newton
normal equations are one dense ``3J × 3J`` system per person, padded (absent joints: identity
rows, they stay NaN) and assembled for all persons at once from ``3 × 3`` blocks
(:func:`normal_equations`, :func:`hessian`). A batched Levenberg-Marquardt
(:func:`levenberg_marquardt`) solves them together: every person has its own damping, accepts
or rejects its own steps and stops on its own tolerance, with the ``ftol`` / ``xtol`` meaning
of ``scipy.optimize.least_squares``. Where the time goes is the damped ``3J × 3J`` solves, so a
step solves only the persons still active, each by an in-place Cholesky (:func:`spd_solve`);
a trial point costs only its residuals (:func:`inner_cost`) and the normal equations are
rebuilt only where a step is accepted and the person goes on.
"""
from __future__ import annotations

import functools
import logging
from dataclasses import dataclass

import numpy as np

from mvm.core.keypoints import BONES, LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER
from mvm.core.prior import body_frame, canonicalize
from mvm.core.quality import row_nanmedian

log = logging.getLogger(__name__)

_BONES = np.array(BONES)
#: ``(B, J)`` bone incidence: +1 at a bone's first joint, -1 at its second.
_INCIDENCE = np.zeros((len(BONES), 17))
_INCIDENCE[np.arange(len(BONES)), _BONES[:, 0]] = 1.0
_INCIDENCE[np.arange(len(BONES)), _BONES[:, 1]] = -1.0
#: Initial damping of every person, relative to the diagonal of its normal equations.
INITIAL_DAMPING = 1e-3
_MIN_DAMPING, _MAX_DAMPING = 1e-9, 1e12


@dataclass
class RefineResult:
    """``X: (P, J, 3)`` refined poses; ``fallback: (P,)`` bool, persons kept at their
    triangulation because refinement made them worse; ``cost_before/after``: the objective."""

    X: np.ndarray
    fallback: np.ndarray
    cost_before: float
    cost_after: float


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
        """Image coordinates ``(P, M, 2, J)`` and depths ``(P, M, J)`` (1 where not fitted) of
        the joints ``X: (P, J, 3)`` in every slot's view."""
        Pn, M = self.P.shape[:2]
        proj = np.matmul(self.P[..., :3].reshape(Pn, 3 * M, 3), np.swapaxes(X, 1, 2)).reshape(Pn, M, 3, -1) \
            + self.P[..., 3, None]
        depth = np.where(self.fit, proj[:, :, 2], 1.0)
        return proj[:, :, :2] / depth[:, :, None], depth

    def reprojection(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residual pixels ``(P, M, J, 2)`` and depths ``(P, M, J)`` of the keypoints at joints
        ``X: (P, J, 3)``; 0 and 1 where a keypoint is not fitted."""
        uv, depth = self._homogeneous(X)
        return np.where(self.fit[..., None], np.swapaxes(uv, 2, 3) - self.xy, 0.0), depth

    def cost(self, X: np.ndarray, w: np.ndarray) -> np.ndarray:
        """``½ Σ w |e|²: (P,)`` of the reprojection rows at ``X: (P, J, 3)``, weights ``w: (P, M, J)``."""
        uv, _ = self._homogeneous(X)
        return 0.5 * np.where(self.fit, w * ((uv - np.swapaxes(self.xy, 2, 3)) ** 2).sum(2), 0.0).sum((1, 2))

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
        c = w / z**2
        coef = np.stack([c, -c * uv[:, :, 0], -c * uv[:, :, 1], c * (uv**2).sum(2)], axis=2)  # (P, M, 4, J)
        blocks = np.matmul(np.swapaxes(coef.reshape(Pn, 4 * M, -1), 1, 2), self.products.reshape(Pn, 4 * M, 9))
        g = w / z
        coef = np.concatenate([g[:, :, None] * e, -(g * (e * uv).sum(2))[:, :, None]], axis=2)  # (P, M, 3, J)
        grad = np.matmul(np.swapaxes(coef.reshape(Pn, 3 * M, -1), 1, 2), self.P[..., :3].reshape(Pn, 3 * M, 3))
        return 0.5 * (w * (e**2).sum(2)).sum((1, 2)), grad, blocks.reshape(Pn, -1, 3, 3)


@dataclass(frozen=True)
class LinearPrior:
    """The linearized prior of every person: residuals ``G @ x − h`` of its joints flattened
    joint-major, ``x: (P, 3J)``. ``G: (P, 3J, 3J)`` (rows beyond a person's ``3n`` present
    coordinates, and persons without a prior, are zero); ``h: (P, 3J)``."""

    G: np.ndarray
    h: np.ndarray

    def take(self, persons: np.ndarray) -> LinearPrior:
        return LinearPrior(self.G[persons], self.h[persons])

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """``(P, 3J)``."""
        return np.matmul(self.G, x[..., None])[..., 0] - self.h

    def energy(self, x: np.ndarray) -> np.ndarray:
        """Half the squared residuals per person, ``(P,)``: at the point of linearization,
        ``weight · ½ |W (X̃ − μ)|²`` of the max-mixture component, the prior's share of the
        objective."""
        return 0.5 * (self.residuals(x) ** 2).sum(1)

    def gram(self) -> np.ndarray:
        """``Gᵀ G: (P, 3J, 3J)``, the prior's constant share of the normal equations."""
        return np.matmul(np.swapaxes(self.G, 1, 2), self.G)


def _prior_groups(X: np.ndarray, present: np.ndarray, prior, weight: float):
    """The body frames and canonical poses of ``X: (P, J, 3)`` (``present: (P, J)``), and the
    (present joints, max-mixture component) pair of every person the prior applies to (both
    hips and shoulders present). Returns ``rotation: (P, 3, 3)``, ``scale: (P,)``, ``canonical:
    (P, J, 3)``, ``keys: (G, J + 1)`` int (present joints, component) and ``which: (P,)``, each
    person's row of ``keys`` (``G``: none)."""
    Pn, J, _ = X.shape
    poses = np.where(present[..., None], X, np.nan)
    frame = body_frame(poses)
    rotation, scale = frame[0], frame[2]                                          # (P, 3, 3), (P,)
    needed = [LEFT_HIP, RIGHT_HIP, LEFT_SHOULDER, RIGHT_SHOULDER]
    usable = present[:, needed].all(1) & np.isfinite(rotation).all((1, 2)) & (scale > 0)
    component = np.full(Pn, -1)
    canonical = np.full_like(poses, np.nan)
    if prior is not None and weight > 0 and usable.any():
        canonical = canonicalize(poses, frame)
        component[usable] = prior.best_component(canonical[usable])
    usable &= component >= 0
    code = (present.astype(np.int64) << np.arange(J)).sum(1) * (1 + max(component.max(), 0)) + component
    codes, first, group = np.unique(code[usable], return_index=True, return_inverse=True)
    first = np.flatnonzero(usable)[first]
    keys = np.concatenate([present[first], component[first, None]], axis=1).astype(int)
    which = np.full(Pn, len(codes))
    which[usable] = group.ravel()
    return rotation, scale, canonical, keys, which


def prior_energy(X: np.ndarray, present: np.ndarray, prior, weight: float) -> np.ndarray:
    """``weight · E_P`` of the max-mixture component (up to its constant) at ``X: (P, J, 3)``,
    ``(P,)`` (0 without a prior): :meth:`LinearPrior.energy` of :func:`linearized_prior` at
    ``X``, without building the linearization."""
    _, _, canonical, keys, which = _prior_groups(X, present, prior, weight)
    energy = np.zeros(len(X))
    for g, key in enumerate(keys):
        rows, mask = np.flatnonzero(which == g), key[:-1].astype(bool)
        mean, W, _ = prior.whitening(mask, int(key[-1]))
        r = (canonical[rows][:, mask].reshape(len(rows), -1) - mean) @ W.T
        energy[rows] = 0.5 * weight * (r**2).sum(1)
    return energy


def linearized_prior(X: np.ndarray, present: np.ndarray, prior, weight: float) -> LinearPrior:
    """Linearize ``weight · E_P`` at ``X: (P, J, 3)`` for every person that has both hips and
    shoulders: the prior's canonicalization ``y_j = R (X_j − pelvis) / s`` with the body frame
    ``R, s`` held fixed (so ``y`` is linear in ``X``) and the max-mixture component, whose
    negative log-likelihood is ``½ |W (y − μ)|²``. ``present: (P, J)`` bool. The whitening of
    each (present joints, component) pair is built once; the others get zero rows."""
    Pn, J, _ = X.shape
    rotation, scale, _, keys, which = _prior_groups(X, present, prior, weight)
    usable = which < len(keys)
    # Per pair: W @ (C ⊗ I) with C = I − ½ (1 e_lh^T + 1 e_rh^T), the pelvis subtraction, on the
    # coordinates of all J joints (zero columns for absent ones), and W @ μ; the last pair: none.
    WC = np.zeros((len(keys) + 1, 3 * J, J, 3))
    Wmean = np.zeros((len(keys) + 1, 3 * J))
    root = np.sqrt(weight)
    for g, key in enumerate(keys):
        mask = key[:J].astype(bool)
        mean, W, _ = prior.whitening(mask, int(key[J]))
        block = W.reshape(len(W), -1, 3)
        total = block.sum(axis=1)
        WC[g, :len(W), mask] = root * np.swapaxes(block, 0, 1)
        WC[g, :len(W), [LEFT_HIP, RIGHT_HIP]] -= 0.5 * root * total
        Wmean[g, :len(W)] = root * (W @ mean)
    frame = np.where(usable[:, None, None], rotation / np.where(usable, scale, 1.0)[:, None, None], 0.0)
    G = np.matmul(WC[which].reshape(Pn, -1, 3), frame).reshape(Pn, 3 * J, 3 * J)
    return LinearPrior(G, Wmean[which])



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


def normal_equations(x: np.ndarray, problem: InnerProblem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Gauss-Newton normal equations of :func:`residuals` ``r`` with Jacobian ``Jr`` at
    ``x: (P, 3J)``: the cost ``½|r|²: (P,)``, the gradient ``Jrᵀ r: (P, 3J)`` and the
    ``3 × 3`` blocks ``(P, K, 3, 3)`` that ``Jrᵀ Jr`` adds to the prior's constant ``Gᵀ G``
    (:func:`hessian`): the ``J`` diagonal blocks (a joint's keypoints and bones), then with bone
    terms the ``(a, b)`` blocks of the :data:`~mvm.core.keypoints.BONES` and their ``(b, a)``."""
    Pn, J = len(x), x.shape[1] // 3
    X = x.reshape(Pn, J, 3)
    cost, grad, blocks = problem.obs.normal_terms(X, problem.sqrt_w**2)
    r_prior = problem.prior.residuals(x)
    cost += 0.5 * (r_prior**2).sum(1)
    grad = grad.reshape(Pn, -1) + np.matmul(r_prior[:, None], problem.prior.G)[:, 0]
    if problem.bones is None:
        return cost, grad, blocks
    r_bone, u = problem.bones.linearize(X)
    cost += 0.5 * (r_bone**2).sum(1)
    grad += np.matmul(_INCIDENCE.T, r_bone[..., None] * u).reshape(Pn, -1)
    uu = (u[..., :, None] * u[..., None, :]).reshape(Pn, -1, 9)                       # (P, B, 9)
    blocks += np.matmul(np.abs(_INCIDENCE.T), uu).reshape(Pn, J, 3, 3)
    return cost, grad, np.concatenate([blocks, -uu.reshape(Pn, -1, 3, 3), -uu.reshape(Pn, -1, 3, 3)], axis=1)


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
    """``Jrᵀ Jr: (P, 3J, 3J)`` from the prior's ``GtG: (P, 3J, 3J)`` and the ``blocks`` of
    :func:`normal_equations` at :func:`block_entries` (added to ``GtG`` itself unless ``copy``)."""
    Pn, n, _ = GtG.shape
    H = GtG.copy() if copy else GtG
    H.reshape(Pn, -1)[:, block_entries(n // 3, blocks.shape[1] > n // 3)] += blocks.reshape(Pn, -1)
    return H


def damped_steps(H: np.ndarray, grad: np.ndarray, damping: np.ndarray) -> np.ndarray:
    """Levenberg-Marquardt steps ``(P, n)``: ``(H + μ diag(H)) δ = −grad`` for ``H: (P, n, n)``
    (overwritten), ``grad: (P, n)``, ``damping μ: (P,)``. A coordinate that no residual depends
    on (a zero diagonal: an absent joint) gets an identity row and does not move."""
    diagonal = H.reshape(len(H), -1)[:, :: H.shape[1] + 1]
    diagonal[:] = np.where(diagonal > 0, diagonal * (1.0 + damping[:, None]), 1.0)
    return -spd_solve(H, grad)


def spd_solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``x: (P, n)`` with ``A x = b`` for ``A: (P, n, n)`` (the damped normal equations,
    symmetric positive definite; not modified), ``b: (P, n)``: numpy's batched LAPACK solve.
    numpy rather than scipy's Cholesky (``posv``): importing scipy.linalg costs more than the
    whole refinement of a rig sequence, and the solve count matters more than the routine. A
    batch holding an exactly singular matrix is solved matrix by matrix, that one by least
    squares."""
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


def inner_cost(x: np.ndarray, problem: InnerProblem) -> np.ndarray:
    """Half the sum of squared :func:`residuals` of every person at ``x: (P, 3J)``, ``(P,)``
    (without forming them)."""
    X = x.reshape(len(x), -1, 3)
    cost = problem.obs.cost(X, problem.sqrt_w**2) + problem.prior.energy(x)
    return cost if problem.bones is None else cost + 0.5 * (problem.bones.linearize(X)[0] ** 2).sum(1)


def levenberg_marquardt(x: np.ndarray, problem: InnerProblem, max_steps: int,
                        tolerance: float) -> np.ndarray:
    """Minimize every person's half sum of squared :func:`residuals` from ``x: (P, 3J)``.

    Each person has its own damping (relative to its normal equations' diagonal: divided by 3
    after an accepted step, multiplied by 10 after a rejected one) and stops on its own when an
    accepted step lowers its cost by less than ``tolerance`` times the cost, or a step is
    shorter than ``tolerance · (tolerance + |x_p|)`` (the ``ftol`` and ``xtol`` of
    ``scipy.optimize.least_squares``), or after ``max_steps`` steps. A trial point costs only
    its residuals; the normal equations are built where a step is accepted and the person goes
    on (only the persons still active are solved). Returns ``(P, 3J)``."""
    x = x.copy()
    cost = inner_cost(x, problem)
    _, grad, blocks = normal_equations(x, problem)
    GtG = problem.prior.gram()
    damping = np.full(len(x), INITIAL_DAMPING)
    active = np.isfinite(cost)
    sub, idx = problem, np.arange(len(x))
    for _ in range(max_steps):
        if not active.any():
            break
        if not active[idx].all():
            idx = np.flatnonzero(active)
            sub = problem.take(idx)
        start, current, mu = x[idx], cost[idx], damping[idx]
        step = damped_steps(hessian(GtG[idx], blocks[idx], copy=False), grad[idx], mu)
        trial = start + step
        trial_cost = inner_cost(trial, sub)
        better = trial_cost < current
        small_step = _norms(step) <= tolerance * (tolerance + _norms(start))
        small_gain = better & (current - trial_cost <= tolerance * current)
        damping[idx] = np.clip(np.where(better, mu / 3.0, mu * 10.0), _MIN_DAMPING, _MAX_DAMPING)
        active[idx] = ~(small_step | small_gain)
        x[idx[better]], cost[idx[better]] = trial[better], trial_cost[better]
        _refresh(trial, grad, blocks, idx, better & active[idx], sub)
    return x


def _norms(x: np.ndarray) -> np.ndarray:
    """Euclidean norms of the rows of ``x: (P, n)``, ``(P,)``."""
    return np.sqrt(np.einsum("pn,pn->p", x, x))


def _refresh(trial: np.ndarray, grad: np.ndarray, blocks: np.ndarray, idx: np.ndarray, moved: np.ndarray,
             sub: InnerProblem) -> None:
    """Rebuild, in place, the gradient and blocks of :func:`normal_equations` of the persons
    ``idx[moved]`` at their accepted ``trial: (Q, 3J)`` points (``sub``: the problem of
    ``idx: (Q,)``, ``moved: (Q,)`` bool)."""
    if moved.all():
        _, grad[idx], blocks[idx] = normal_equations(trial, sub)
    elif moved.any():
        rows = np.flatnonzero(moved)
        _, grad[idx[rows]], blocks[idx[rows]] = normal_equations(trial[rows], sub.take(rows))


def objective(X: np.ndarray, obs: Observations, energy: np.ndarray, robust_scale_px: float,
              bones: BoneTerms | None = None) -> float:
    """Σ c ρ(e²) + λ E_P (up to the mixture's constants) [+ the bone terms] at ``X: (P, J, 3)``
    (absent joints 0), ``energy: (P,)`` the prior's (:meth:`LinearPrior.energy` at ``X``)."""
    e, _ = obs.reprojection(X)
    f2 = robust_scale_px**2
    total = (np.where(obs.fit, obs.conf, 0.0) * 2 * f2 * (np.sqrt(1 + (e**2).sum(-1) / f2) - 1)).sum()
    total += 0.5 * np.sum(bones.linearize(X)[0] ** 2) if bones is not None else 0.0
    return float(total + np.sum(energy))


def irls_weights(X: np.ndarray, obs: Observations, robust_scale_px: float) -> np.ndarray:
    """``sqrt(2 ρ'(e²) c)`` of soft-L1 at ``X: (P, J, 3)``, ``(P, M, J)`` (0 where not fitted)."""
    e, _ = obs.reprojection(X)
    robust_w = 1.0 / np.sqrt(1.0 + (e**2).sum(-1) / robust_scale_px**2)
    return np.sqrt(2.0 * robust_w * np.where(obs.fit, obs.conf, 0.0))


def fallback_persons(X0: np.ndarray, X: np.ndarray, present: np.ndarray, obs: Observations,
                     robust_scale_px: float) -> np.ndarray:
    """``(P,)`` bool: observed persons whose refinement is not finite, has a median
    reprojection error above twice the triangulation's plus ``robust_scale_px``, or puts a
    fitted joint behind a camera. ``X0, X: (P, J, 3)``."""
    with np.errstate(all="ignore"):
        e0, _ = obs.reprojection(np.where(present[..., None], X0, 0.0))
        e1, depth1 = obs.reprojection(np.where(present[..., None], X, 0.0))
    observed = obs.fit.any((1, 2))
    finite = np.where(present[..., None], np.isfinite(X), True).all((1, 2))

    def median_error(e):
        return row_nanmedian(np.where(obs.fit, np.linalg.norm(e, axis=-1), np.nan).reshape(len(X), -1))

    worse = median_error(e1) > 2.0 * median_error(e0) + robust_scale_px
    behind = ~(depth1 > 0).all((1, 2))
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
        max_iterations: Levenberg-Marquardt steps per person and outer iteration.
        outer_iterations: re-linearizations of the robust loss and the prior.
        bone_lengths: ``(P, B)`` lengths of :data:`mvm.core.keypoints.BONES` each person's bones
            are pulled to (NaN: none), e.g. its track's; ``bone_weight``: pixels² per squared
            relative length error (0: no bone term).
        tolerance: relative change of a person's cost, and of its joints, at which its inner
            solve stops (the ``ftol``, ``xtol`` of :func:`levenberg_marquardt`).
    Returns :class:`RefineResult`.
    """
    X0 = np.asarray(X0, dtype=float)
    Pn, J, _ = X0.shape
    present = np.isfinite(X0).all(-1)                                    # (P, J)
    obs = Observations.build(np.asarray(xy, dtype=float), np.asarray(P, dtype=float), np.asarray(conf, dtype=float),
                       np.asarray(inliers, bool) & present[:, None, :])
    if not obs.fit.any():
        return RefineResult(X0.copy(), np.zeros(Pn, bool), 0.0, 0.0)
    use_prior = prior is not None and prior_weight > 0
    bones = (BoneTerms.build(bone_lengths, bone_weight, present)
             if bone_lengths is not None and bone_weight > 0 else None)
    prior = prior if use_prior else None

    X = np.where(present[..., None], X0, 0.0)
    linear = linearized_prior(X, present, prior, prior_weight)
    cost_before = objective(X, obs, linear.energy(X.reshape(Pn, -1)), robust_scale_px, bones)
    for k in range(outer_iterations):
        linear = linearized_prior(X, present, prior, prior_weight) if k else linear
        problem = InnerProblem(obs, irls_weights(X, obs, robust_scale_px), linear, bones)
        X = levenberg_marquardt(X.reshape(Pn, -1), problem, max_iterations, tolerance).reshape(Pn, J, 3)
    X = np.where(present[..., None], X, np.nan)
    fallback = fallback_persons(X0, X, present, obs, robust_scale_px)
    X[fallback] = X0[fallback]
    if fallback.any():
        log.warning("refinement diverged for %d person(s); kept their triangulation", int(fallback.sum()))
    X_fit = np.where(present[..., None], X, 0.0)
    cost_after = objective(X_fit, obs, prior_energy(X_fit, present, prior, prior_weight), robust_scale_px, bones)
    return RefineResult(X, fallback, cost_before, cost_after)
