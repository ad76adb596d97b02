"""The Gaussian-mixture pose prior of the refinement (Eq. bundle): ``E_P(X) = -log Σ_l w_l N(X | μ_l, Σ_l)``.

Poses are compared in a canonical frame built from the pose itself (``canonicalize``), so the
prior ignores where a person stands, which way they face and how tall they are. The mixture
has 8 full-covariance components fitted on real poses (CMU motion capture and CMU Panoptic,
``scripts/build_pose_data.py``); the fitted parameters ship in ``data/pose_prior.npz``.

Missing joints are marginalized out: the likelihood of the present joints under each
component is the Gaussian with the rows and columns of the present coordinates.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.core.config import Config
from mvm.core.geometry import cross
from mvm.core.keypoints import LEFT_HIP, LEFT_SHOULDER, NUM_JOINTS, RIGHT_HIP, RIGHT_SHOULDER
from mvm.core.shipped import read_arrays
from mvm.errors import InputError

#: Dimension of a flattened canonical pose (joint-major: x0, y0, z0, x1, ...).
DIM = 3 * NUM_JOINTS
#: Default number of mixture components (the paper's 8).
COMPONENTS = 8
#: Variance added to the diagonal of every covariance when fitting, in canonical units
#: (torso lengths squared: 1e-3 is a standard deviation of 3 % of the torso, about 1.5 cm).
#: The canonical frame fixes six coordinates (hips on the x axis, the mid-shoulders in the
#: x-z plane), so the sample covariances are singular; this floor makes them invertible and
#: keeps the prior tolerant of joints defined slightly differently from the training data
#: (derived face points, other marker conventions).
REG_COVAR = 1e-3
_EPS = 1e-9


def logsumexp(a: np.ndarray, axis: int = -1) -> np.ndarray:
    """``log Σ exp(a)`` along ``axis``, with the maximum factored out (exact for -inf entries).

    Here rather than ``scipy.special.logsumexp``: importing scipy.special costs more than the
    refinement of a whole rig sequence, and the rig command imports no scipy at all.

    >>> float(logsumexp(np.log([1.0, 2.0, 3.0])))
    1.791759469228055
    >>> round(float(logsumexp(np.array([1000.0, 1000.0])) - 1000.0), 12)     # no overflow
    0.69314718056
    >>> float(logsumexp(np.array([-np.inf, -np.inf])))
    -inf
    """
    a = np.asarray(a, dtype=float)
    top = np.max(a, axis=axis, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        return np.log(np.exp(a - top).sum(axis=axis)) + np.squeeze(top, axis=axis)


def body_frame(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The body frame of ``canonicalize``. ``poses: (..., 17, 3)`` ->
    ``(rotation: (..., 3, 3), centre: (..., 3), scale: (...))``.

    ``rotation``'s rows are the body axes in world coordinates: x from the right hip to the left
    hip; z from the pelvis to the mid-shoulders, made orthogonal to x; y = z × x. ``centre`` is
    the pelvis (mid-hips), ``scale`` the torso length (mean of the left and right
    shoulder-to-hip distances). Canonical coordinates are ``rotation @ (X - centre) / scale``.
    Poses lacking a hip or a shoulder, or with coincident hips, give NaN.

    A person standing at (1, 2, 0), hips 0.3 apart along x, shoulders 0.5 above them: the body
    axes are the world's:

    >>> pose = np.zeros((17, 3)) + [1.0, 2.0, 0.0]
    >>> pose[LEFT_HIP, 0], pose[RIGHT_HIP, 0] = 1.15, 0.85
    >>> pose[LEFT_SHOULDER] = [1.15, 2.0, 0.5]
    >>> pose[RIGHT_SHOULDER] = [0.85, 2.0, 0.5]
    >>> rotation, centre, scale = body_frame(pose)
    >>> rotation.round(9), centre, float(scale)
    (array([[1., 0., 0.],
           [0., 1., 0.],
           [0., 0., 1.]]), array([1., 2., 0.]), 0.5)
    """
    poses = np.asarray(poses, dtype=float)
    if poses.ndim < 2 or poses.shape[-2:] != (NUM_JOINTS, 3):
        raise ValueError(f"expected poses (..., 17, 3), got {poses.shape}")
    lh, rh = poses[..., LEFT_HIP, :], poses[..., RIGHT_HIP, :]
    ls, rs = poses[..., LEFT_SHOULDER, :], poses[..., RIGHT_SHOULDER, :]
    centre = 0.5 * (lh + rh)
    x = lh - rh
    x_norm = np.linalg.norm(x, axis=-1, keepdims=True)
    up = 0.5 * (ls + rs) - centre
    scale = 0.5 * (np.linalg.norm(ls - lh, axis=-1) + np.linalg.norm(rs - rh, axis=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        x = x / x_norm
        z = up - np.sum(up * x, axis=-1, keepdims=True) * x
        z_norm = np.linalg.norm(z, axis=-1, keepdims=True)
        z = z / z_norm
        rotation = np.stack([x, cross(z, x), z], axis=-2)
    degenerate = ~((x_norm[..., 0] > _EPS * scale) & (z_norm[..., 0] > _EPS * scale) & (scale > _EPS))
    rotation[degenerate] = np.nan
    scale = np.where(degenerate, np.nan, scale)
    return rotation, centre, scale


def canonicalize(poses: np.ndarray, frame: tuple | None = None) -> np.ndarray:
    """World poses in the pose's own body frame, scale-normalized. ``poses: (..., 17, 3)`` -> ``(..., 17, 3)``.

    Origin: the pelvis (mid-hips). Axes: x from the right hip to the left hip; z from the pelvis
    to the mid-shoulders, made orthogonal to x; y = z × x (towards the back). Scale: divided by
    the torso length, the mean of the left and right shoulder-to-hip distances (``body_frame``).
    The result does not depend on the world's rotation, translation or scale. NaN joints stay
    NaN; a pose lacking a hip or a shoulder (or with coincident hips) is all NaN. ``frame``:
    the poses' ``body_frame`` when the caller already has it.

    >>> pose = np.random.default_rng(0).normal(size=(17, 3))
    >>> q, _ = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))
    >>> moved = 3.0 * pose @ (q * np.sign(np.linalg.det(q))).T + [1.0, -2.0, 0.5]
    >>> np.allclose(canonicalize(moved), canonicalize(pose))
    True
    """
    rotation, centre, scale = body_frame(poses) if frame is None else frame
    with np.errstate(invalid="ignore"):
        return np.einsum("...ij,...kj->...ki", rotation, np.asarray(poses, dtype=float) - centre[..., None, :]) \
            / scale[..., None, None]


@dataclass(frozen=True, eq=False)
class PosePrior:
    """A Gaussian mixture over flattened canonical poses.

    Attributes:
        weights: ``(L,)`` mixture weights (sum 1); means: ``(L, 51)`` canonical poses flattened
        joint-major (x0, y0, z0, x1, ...); covariances: ``(L, 51, 51)`` symmetric positive definite.

    Instances compare by identity (the arrays make value equality ambiguous); ``whitening``
    results are cached per instance.
    """

    weights: np.ndarray
    means: np.ndarray
    covariances: np.ndarray

    def __post_init__(self):
        weights = np.asarray(self.weights, dtype=float)
        means = np.asarray(self.means, dtype=float)
        covariances = np.asarray(self.covariances, dtype=float)
        count = len(weights)
        if weights.shape != (count,) or means.shape != (count, DIM) or covariances.shape != (count, DIM, DIM):
            raise ValueError(f"expected weights (L,), means (L, {DIM}), covariances (L, {DIM}, {DIM}), "
                             f"got {weights.shape}, {means.shape}, {covariances.shape}")
        if count == 0 or np.any(weights <= 0) or not math.isclose(weights.sum(), 1.0, rel_tol=1e-6):
            raise ValueError(f"mixture weights must be positive and sum to 1, got {weights}")
        if not np.allclose(covariances, np.swapaxes(covariances, 1, 2)):
            raise ValueError("covariances must be symmetric")
        for name, value in (("weights", weights), ("means", means), ("covariances", covariances)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "_whitening", functools.lru_cache(maxsize=1024)(self._whitening_uncached))
        object.__setattr__(self, "_stacked", functools.lru_cache(maxsize=256)(self._stacked_uncached))

    @classmethod
    def load(cls, path: str | Path | None = None) -> PosePrior:
        """Read a prior ``.npz`` (arrays ``weights``, ``means``, ``covariances``); default: the shipped one."""
        arrays = read_arrays(path, "pose_prior.npz", ("weights", "means", "covariances"), "a pose prior")
        try:
            return cls(**arrays)
        except ValueError as e:
            raise InputError(path or "mvm/data/pose_prior.npz", None, str(e)) from None

    @property
    def components(self) -> int:
        return len(self.weights)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The arrays ``load`` reads, for ``np.savez``."""
        return {"weights": self.weights, "means": self.means, "covariances": self.covariances}

    # --- densities --------------------------------------------------------------------------

    def log_weighted_densities(self, canonical: np.ndarray) -> np.ndarray:
        """``log(w_l N(x_obs | μ_l,obs, Σ_l,obs))`` of every pose and component.

        ``canonical: (P, 17, 3)`` with NaN for missing joints (a joint with any NaN coordinate
        is missing) -> ``(P, L)``; all-NaN poses give NaN rows.
        """
        canonical = np.asarray(canonical, dtype=float)
        if canonical.ndim != 3 or canonical.shape[1:] != (NUM_JOINTS, 3):
            raise ValueError(f"expected canonical poses (P, 17, 3), got {canonical.shape}")
        present = ~np.isnan(canonical).any(axis=-1)                                  # (P, 17)
        flat = canonical.reshape(len(canonical), DIM)
        out = np.full((len(canonical), self.components), np.nan)
        code = present.astype(np.int64) @ (1 << np.arange(NUM_JOINTS))
        for pattern in dict.fromkeys(code.tolist()):            # the patterns (a few), first seen first
            if pattern == 0:
                continue
            rows = np.flatnonzero(code == pattern)
            mask = present[rows[0]]
            stacked, shift, c = self._stacked(mask.tobytes())                        # (K, L K), (L K,), (L,)
            x = flat[rows] if mask.all() else flat[rows][:, np.repeat(mask, 3)]      # (n, K)
            r = (x @ stacked - shift).reshape(len(rows), len(c), -1)                 # (n, L, K): W_l (x − μ_l)
            out[rows] = (-0.5 * np.einsum("nlk,nlk->nl", r, r)) - c
        return out

    def _stacked_uncached(self, present_bytes: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The :meth:`whitening` of every component for one pattern of present joints, as one
        product: ``W_l (x − μ_l)`` of all ``l`` is ``x @ stacked − shift`` with ``stacked: (K, L K)``
        the ``W_lᵀ`` side by side and ``shift: (L K,)`` the ``W_l μ_l``; and ``c: (L,)``."""
        present = np.frombuffer(present_bytes, dtype=bool)
        parts = [self.whitening(present, component) for component in range(self.components)]
        stacked = np.concatenate([w.T for _, w, _ in parts], axis=1)
        shift = np.concatenate([w @ mean for mean, w, _ in parts])
        return stacked, shift, np.array([c for _, _, c in parts])

    def nll(self, canonical: np.ndarray) -> np.ndarray:
        """``E_P``: ``-log Σ_l w_l N(x_obs | μ_l,obs, Σ_l,obs)``. ``canonical: (P, 17, 3)`` -> ``(P,)``.

        Missing (NaN) joints are marginalized out; an all-NaN pose gives NaN.
        """
        log_terms = self.log_weighted_densities(canonical)
        out = np.full(len(log_terms), np.nan)
        valid = ~np.isnan(log_terms).any(axis=1)
        out[valid] = -logsumexp(log_terms[valid], axis=1)
        return out

    def responsibilities(self, canonical: np.ndarray) -> np.ndarray:
        """The posterior probability of every component given the present joints.
        ``canonical: (P, 17, 3)`` with NaN for missing joints -> ``(P, L)``, rows summing to 1
        (NaN rows for all-NaN poses)."""
        log_terms = self.log_weighted_densities(canonical)
        return np.exp(log_terms - logsumexp(log_terms, axis=1)[:, None])

    def best_component(self, canonical: np.ndarray) -> np.ndarray:
        """The max-mixture component: ``argmax_l w_l N(x_obs | …)``. ``canonical: (P, 17, 3)`` ->
        ``(P,)`` int, -1 for all-NaN poses."""
        log_terms = self.log_weighted_densities(canonical)
        valid = ~np.isnan(log_terms).any(axis=1)
        return np.where(valid, np.argmax(np.where(valid[:, None], log_terms, 0.0), axis=1), -1)

    def whitening(self, present: np.ndarray, component: int) -> tuple[np.ndarray, np.ndarray, float]:
        """Whitening of one component's marginal over the present joints.

        ``present: (17,)`` bool -> ``(mean_obs: (K,), W: (K, K), c)`` with ``K = 3 * present.sum()``
        such that ``r = W @ (x_obs - mean_obs)`` gives ``0.5 * |r|² + c = -log(w_l N(x_obs | μ_l,obs, Σ_l,obs))``.
        ``W`` is the inverse of the Cholesky factor of ``Σ_l,obs`` (lower triangular). Results are
        cached and read-only.
        """
        present = np.asarray(present, dtype=bool)
        if present.shape != (NUM_JOINTS,):
            raise ValueError(f"expected present (17,) bool, got shape {present.shape}")
        if not present.any():
            raise ValueError("no joint present: the marginal of an empty pose is undefined")
        if not 0 <= component < self.components:
            raise ValueError(f"component must be in [0, {self.components}), got {component}")
        return self._whitening(present.tobytes(), int(component))

    def _whitening_uncached(self, present_bytes: bytes, component: int) -> tuple[np.ndarray, np.ndarray, float]:
        coords = np.repeat(np.frombuffer(present_bytes, dtype=bool), 3)
        mean = self.means[component, coords].copy()
        factor = np.linalg.cholesky(self.covariances[component][np.ix_(coords, coords)])
        w = np.tril(np.linalg.inv(factor))                      # the inverse of a lower factor is lower
        c = (-math.log(self.weights[component]) + 0.5 * len(mean) * math.log(2.0 * math.pi)
             + float(np.log(np.diag(factor)).sum()))
        mean.setflags(write=False)
        w.setflags(write=False)
        return mean, w, c


@functools.lru_cache(maxsize=1)
def shipped_prior() -> PosePrior:
    """The prior that ships with mvm (``mvm/data/pose_prior.npz``), read once per process."""
    return PosePrior.load()


def load_prior(config: Config, prior: PosePrior | None = None) -> PosePrior | None:
    """The pose prior of the refinement, the same rule for a scene and for a rig.

    Returns ``prior`` when one is given; None when the refinement does not use a prior
    (``config.refine`` off or ``config.prior_weight <= 0``); otherwise :func:`shipped_prior`.
    Raises :class:`~mvm.errors.InputError` naming the file when the shipped prior cannot be
    read: a broken installation fails loudly rather than refining without the prior.
    """
    if prior is not None or not config.refine or config.prior_weight <= 0:
        return prior
    return shipped_prior()


def fit_pose_prior(canonical: np.ndarray, components: int = COMPONENTS, reg_covar: float = REG_COVAR,
                   random_state: int = 0, n_init: int = 2, max_iter: int = 500) -> tuple[PosePrior, dict]:
    """Fit the mixture on complete canonical poses with scikit-learn (an optional dependency).

    ``canonical: (N, 17, 3)`` without NaN -> ``(prior, info)``; ``info`` holds the mean
    log-likelihood per pose, the iterations and whether EM converged.
    """
    from sklearn.mixture import GaussianMixture

    canonical = np.asarray(canonical, dtype=float)
    if canonical.ndim != 3 or canonical.shape[1:] != (NUM_JOINTS, 3):
        raise ValueError(f"expected canonical poses (N, 17, 3), got {canonical.shape}")
    if np.isnan(canonical).any():
        raise ValueError("fit on complete poses only (found NaN)")
    x = canonical.reshape(len(canonical), DIM)
    gmm = GaussianMixture(n_components=components, covariance_type="full", reg_covar=reg_covar,
                          random_state=random_state, n_init=n_init, max_iter=max_iter)
    gmm.fit(x)
    prior = PosePrior(gmm.weights_ / gmm.weights_.sum(), gmm.means_,
                      0.5 * (gmm.covariances_ + np.swapaxes(gmm.covariances_, 1, 2)))
    info = {"poses": len(x), "mean_log_likelihood": float(gmm.score(x)), "iterations": int(gmm.n_iter_),
            "converged": bool(gmm.converged_), "reg_covar": reg_covar, "random_state": random_state}
    return prior, info
