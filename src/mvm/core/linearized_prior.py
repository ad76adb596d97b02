"""The pose prior linearized for the refinement's least-squares solve (:mod:`mvm.core.refine`).

With a person's body frame (rotation ``R``, scale ``s``) and max-mixture component held fixed,
the prior's negative log-likelihood ``½ |W (X̃ − μ)|²`` of its canonical pose ``X̃`` is a sum
of squares linear in the joints; its matrices depend only on the person's present joints and
component, so they are built once per such group (:class:`LinearPrior`, cached).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from mvm.core.keypoints import LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER
from mvm.core.prior import body_frame, canonicalize


@dataclass(frozen=True)
class LinearPrior:
    """The linearized prior of every person, in its body basis.

    A person's canonical coordinates ``y_j = R (X_j − pelvis) / s`` are linear in its joints
    once the frame ``R, s`` is held fixed: its prior residuals are ``M_g (x̂ / s) − h_g`` with
    ``x̂ = (R X_j)_j`` the joints in the body basis, flattened joint-major, and ``M_g: (3J, 3J)``,
    ``h_g: (3J,)`` shared by every person of the same (present joints, mixture component) group
    ``g`` (the whitening, the pelvis subtraction and ``√weight``; zero rows beyond the present
    coordinates). Nothing per person is ``3J × 3J``: residuals are one product per group, and
    the prior's share of the normal equations in the body basis is the group's ``M_gᵀ M_g / s²``.

    ``rotation: (P, 3, 3)`` ``R`` (identity without a prior), ``scale: (P,)`` ``s`` (1 without);
    ``which: (P,)`` each person's group (``G``: none); ``M: (G + 1, 3J, 3J)``, ``h: (G + 1, 3J)``
    and ``gram_body: (G + 1, 3J, 3J)``, the ``M_gᵀ M_g`` of a unit weight (the last group's:
    zero); ``weight: (P,)`` each person's weight ``λ`` (positive where it has a group): its
    residuals are ``√λ`` times its group's, its share of the normal equations ``λ`` times."""

    rotation: np.ndarray
    scale: np.ndarray
    which: np.ndarray
    M: np.ndarray
    h: np.ndarray
    gram_body: np.ndarray
    weight: np.ndarray

    def take(self, persons: np.ndarray) -> LinearPrior:
        return LinearPrior(self.rotation[persons], self.scale[persons], self.which[persons], self.M, self.h,
                           self.gram_body, self.weight[persons])

    @functools.cached_property
    def _gathered(self) -> np.ndarray:
        """``M_g`` of every person, ``(P, 3J, 3J)`` (gathered once, for few persons per group)."""
        return self.M[self.which]

    @functools.cached_property
    def _groups(self) -> list:
        """``(g, rows)`` of every group that has persons, but the last (persons without a prior)."""
        return [(g, np.flatnonzero(self.which == g)) for g in np.unique(self.which) if g < len(self.M) - 1]

    def _times(self, y: np.ndarray, transpose: bool = False) -> np.ndarray:
        """``M_g y`` (``M_gᵀ y`` if ``transpose``) of every person, ``y: (P, 3J)``. One product
        per group; with few persons per group, one gather of their matrices."""
        if len(self.which) <= 2 * len(self.M):
            M = self._gathered
            return np.matmul(y[:, None], M)[:, 0] if transpose else np.matmul(M, y[..., None])[..., 0]
        out = np.zeros_like(y)
        for g, rows in self._groups:
            out[rows] = y[rows] @ (self.M[g] if transpose else self.M[g].T)
        return out

    def to_body(self, x: np.ndarray) -> np.ndarray:
        """``x: (P, 3J)`` world coordinates (or gradients) -> ``(P, 3J)`` rotated into each
        person's body basis."""
        return np.matmul(x.reshape(len(x), -1, 3), np.swapaxes(self.rotation, 1, 2)).reshape(len(x), -1)

    def to_world(self, x: np.ndarray) -> np.ndarray:
        """The inverse rotation of :meth:`to_body`."""
        return np.matmul(x.reshape(len(x), -1, 3), self.rotation).reshape(len(x), -1)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """``(P, 3J)`` at ``x: (P, 3J)``; zero for persons without a prior."""
        unit = self._times(self.to_body(x) / self.scale[:, None]) - self.h[self.which]
        return np.sqrt(self.weight)[:, None] * unit

    def energy_gradient(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Half the squared residuals per person ``(P,)`` and their gradient by ``x``, ``(P, 3J)``."""
        r = self.residuals(x)
        grad = self.to_world(self._times(r, transpose=True)) * (np.sqrt(self.weight) / self.scale)[:, None]
        return 0.5 * np.einsum("pn,pn->p", r, r), grad

    def energy(self, x: np.ndarray) -> np.ndarray:
        """Half the squared residuals per person, ``(P,)``: at the point of linearization,
        ``weight · ½ |W (X̃ − μ)|²`` of the max-mixture component, the prior's share of the
        objective."""
        r = self.residuals(x)
        return 0.5 * np.einsum("pn,pn->p", r, r)

    def gram(self) -> np.ndarray:
        """The prior's share of the normal equations in world coordinates, ``Rᵀ M_gᵀ M_g R / s²``
        per joint block, ``(P, 3J, 3J)`` (the solver works in the body basis and never forms it)."""
        Pn, n = len(self.which), self.gram_body.shape[1]
        H = (self.gram_body[self.which] * (self.weight / self.scale**2)[:, None, None]).reshape(Pn, n // 3, 3, n)
        H = np.matmul(np.swapaxes(self.rotation, 1, 2)[:, None], H).reshape(Pn, n, n // 3, 3)
        return np.matmul(H, self.rotation[:, None]).reshape(Pn, n, n)


def _prior_groups(X: np.ndarray, present: np.ndarray, prior, weight: np.ndarray):
    """The body frames of ``X: (P, J, 3)`` (``present: (P, J)``), and the (present joints,
    max-mixture component) pair of every person the prior applies to (both hips and shoulders
    present, ``weight: (P,)`` positive). Returns ``rotation: (P, 3, 3)``, ``scale: (P,)``, ``keys: (G, J + 1)`` int
    (present joints, component) and ``which: (P,)``, each person's row of ``keys`` (``G``: none)."""
    Pn, J, _ = X.shape
    poses = np.where(present[..., None], X, np.nan)
    frame = body_frame(poses)
    rotation, scale = frame[0], frame[2]                                          # (P, 3, 3), (P,)
    needed = [LEFT_HIP, RIGHT_HIP, LEFT_SHOULDER, RIGHT_SHOULDER]
    usable = present[:, needed].all(1) & np.isfinite(rotation).all((1, 2)) & (scale > 0) & (weight > 0)
    if prior is not None and usable.any():
        # Every person at once: the others' canonical poses are NaN, their component -1.
        component = np.where(usable, prior.best_component(canonicalize(poses, frame)), -1)
    else:
        component = np.full(Pn, -1)
    usable &= component >= 0
    code = (present.astype(np.int64) << np.arange(J)).sum(1) * (1 + max(component.max(), 0)) + component
    rows = np.flatnonzero(usable)
    groups: dict = {}                                      # code -> (group, first person); a few groups
    group = [groups.setdefault(c, (len(groups), p))[0] for c, p in zip(code[rows].tolist(), rows.tolist())]
    first = np.array([p for _, p in groups.values()], dtype=int)
    keys = np.concatenate([present[first], component[first, None]], axis=1).astype(int)
    which = np.full(Pn, len(groups))
    which[rows] = group
    return rotation, scale, keys, which


def prior_energy(X: np.ndarray, present: np.ndarray, prior, weight: float | np.ndarray) -> np.ndarray:
    """``weight · E_P`` of the max-mixture component (up to its constant) at ``X: (P, J, 3)``,
    ``(P,)`` (0 without a prior; ``weight``: one for all or ``(P,)``): :meth:`LinearPrior.energy`
    of :func:`linearized_prior` at ``X``."""
    return linearized_prior(X, present, prior, weight).energy(X.reshape(len(X), -1))


@functools.lru_cache(maxsize=256)
def _group_matrices(prior, present: bytes, component: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The linearized prior of one (present joints, component) group (:class:`LinearPrior`),
    of a unit weight: ``M: (3J, 3J)``, ``h: (3J,)`` and ``Mᵀ M`` (cached, read-only).
    ``present``: the ``(J,)`` bool mask's bytes."""
    mask = np.frombuffer(present, dtype=bool)
    J = len(mask)
    mean, W, _ = prior.whitening(mask, component)
    # W @ (C ⊗ I) with C = I − ½ (1 e_lh^T + 1 e_rh^T), the pelvis subtraction, on the
    # coordinates of all J joints (zero columns for absent ones), and W @ μ.
    block = W.reshape(len(W), -1, 3)
    M = np.zeros((3 * J, J, 3))
    M[:len(W), mask] = block
    M[:len(W), [LEFT_HIP, RIGHT_HIP]] -= 0.5 * block.sum(axis=1)[:, None]
    M = M.reshape(3 * J, 3 * J)
    h = np.zeros(3 * J)
    h[:len(W)] = W @ mean
    out = (M, h, M.T @ M)
    for a in out:
        a.setflags(write=False)
    return out


def linearized_prior(X: np.ndarray, present: np.ndarray, prior, weight: float | np.ndarray) -> LinearPrior:
    """Linearize ``weight · E_P`` at ``X: (P, J, 3)`` for every person that has both hips and
    shoulders and a positive weight (``weight``: one for all, or each person's ``(P,)``): the
    prior's canonicalization ``y_j = R (X_j − pelvis) / s`` with the body frame ``R, s`` held
    fixed (so ``y`` is linear in ``X``) and the max-mixture component, whose negative
    log-likelihood is ``½ |W (y − μ)|²``. ``present: (P, J)`` bool. The whitening of each
    (present joints, component) pair is built once (:class:`LinearPrior`)."""
    J = X.shape[1]
    weight = np.broadcast_to(np.asarray(weight, dtype=float), (len(X),))
    rotation, scale, keys, which = _prior_groups(X, present, prior, weight)
    usable = which < len(keys)
    M, h, gram = _stacked_matrices(prior, keys.tobytes(), len(keys), J)
    rotation = np.where(usable[:, None, None], rotation, np.eye(3))
    return LinearPrior(rotation, np.where(usable, scale, 1.0), which, M, h, gram, np.where(usable, weight, 1.0))


@functools.lru_cache(maxsize=32)
def _stacked_matrices(prior, keys: bytes, groups: int, J: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_group_matrices` of the ``groups`` (present joints, component) rows of ``keys``
    (the ``(G, J + 1)`` int array's bytes), stacked with the zero group of the persons without
    a prior: ``M, gram: (G + 1, 3J, 3J)``, ``h: (G + 1, 3J)`` (cached, read-only: the outer
    iterations of a scene mostly meet the same groups again)."""
    rows = np.frombuffer(keys, dtype=int).reshape(groups, J + 1)
    M, gram = np.zeros((2, groups + 1, 3 * J, 3 * J))
    h = np.zeros((groups + 1, 3 * J))
    for g, key in enumerate(rows):
        M[g], h[g], gram[g] = _group_matrices(prior, key[:J].astype(bool).tobytes(), int(key[J]))
    for a in (M, h, gram):
        a.setflags(write=False)
    return M, h, gram

