"""A joint through a gap of a track: a least-acceleration curve held at its bone's length from
its parent joint, pulled weakly to the pose prior's guess and to the rays of the few views that
still see it.

The unknowns are the joint's offsets from its parent, ``r_t = x_t - parent_t``, at the ``n``
instants of a gap (the parent is known there: seen, or filled first). Each is a Gaussian
residual (the weighted least squares of a Gauss-Newton solve, vectorized over gaps of one
length):

- **motion**: the second differences of ``r`` over the gap and the two known offsets on either
  side, standard deviation ``sigma_acc`` (the track's own accelerations of that offset);
- **bone**: ``|r_t| - L``, standard deviation ``sigma_bone`` (linearized about the current
  estimate: the joint stays on the sphere of the bone's length around its parent);
- **rays**: the distance of ``x_t`` to each ray of a view's 2D keypoint of the joint,
  standard deviation ``sigma_ray``, Cauchy-weighted and gated (a keypoint far from the fit is
  another person's or an outlier). One view fixes the joint to a line; the bone fixes it to a
  sphere; their meeting nearest the motion's guess is the fill, which interpolation cannot find;
- **prior**: the offset the pose prior expects from the rest of the body, ``sigma_prior``
  (weighed less, ``prior_where_seen``, where a view the motion agrees with sees the joint).

The posterior standard deviation of each filled instant (the inverse of the normal matrix)
grows towards the middle of a gap and with its length, and shrinks where a ray sees the joint.
Arrays in, arrays out; no I/O. Units: those of the arrays (metres in the rig driver's calls).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Gauss-Newton iterations (bone linearization, ray weights).
ITERATIONS = 6
#: Instants next to a known side of a gap where a view's rays are tried against the motion. [1]
END_INSTANTS = 3
#: A ray's Cauchy weight halves at this many ``sigma_ray`` from the fit. [1]
RAY_CAUCHY = 3.0
#: Times the gate of ``fit_gaps``' ``gate_sigmas`` is doubled for a gap whose rays it refuses all. [1]
GATE_DOUBLINGS = 3


def second_differences(n: int) -> np.ndarray:
    """``(n + 2, n + 4)``: the second differences of a chain of ``n + 4`` values (two known ones
    before a gap of ``n``, two after).

    >>> second_differences(1)
    array([[ 1., -2.,  1.,  0.,  0.],
           [ 0.,  1., -2.,  1.,  0.],
           [ 0.,  0.,  1., -2.,  1.]])
    >>> second_differences(2) @ np.arange(6.0)        # a straight line has no acceleration
    array([0., 0., 0., 0.])
    """
    D = np.zeros((n + 2, n + 4))
    i = np.arange(n + 2)
    D[i, i], D[i, i + 1], D[i, i + 2] = 1.0, -2.0, 1.0
    return D


@dataclass
class _Gaps:
    """The terms of ``N`` gaps of ``n`` instants: ``motion (N, n, n)`` (the normal matrix of the
    second differences, one per axis), ``fixed (N, n, 3, 3)`` and ``rhs (N, n, 3)`` (motion and
    prior), ``chain`` for the objective (``D (n + 2, n + 4)``, ``known (N, 4, 3)``, ``w_acc
    (N, n + 2)``), the bone (``bone, w_bone (N,)``), the prior (``prior (N, n, 3)``, its weights
    ``w_prior (N, n)``) and the rays (``present (N, n, R)``,
    origins and directions ``(N, n, R, 3)``, ``proj (N, n, R, 3, 3)`` onto each ray's normal plane)."""

    motion: np.ndarray
    fixed: np.ndarray
    rhs: np.ndarray
    D: np.ndarray
    known: np.ndarray
    w_acc: np.ndarray
    bone: np.ndarray
    w_bone: np.ndarray
    prior: np.ndarray | None
    w_prior: np.ndarray
    present: np.ndarray | None = None
    origin: np.ndarray | None = None
    direction: np.ndarray | None = None
    proj: np.ndarray | None = None
    sigma_ray: float = np.inf
    gate: float = np.inf

    @property
    def rays(self) -> bool:
        return self.present is not None


def _gaps(before, after, bone, sigma_acc, sigma_bone, prior, sigma_prior, ray_origin, ray_direction,
          sigma_ray, gate, n: int) -> _Gaps:
    """The terms of :func:`fit_gaps`' problem (arguments as there, checked)."""
    N = len(before)
    D = second_differences(n)
    known = np.concatenate([before, after], 1)                                     # (N, 4, 3)
    kcols = np.array([0, 1, n + 2, n + 3])
    # rows touching an unknown known are dropped
    row_ok = ~((D[None][:, :, kcols] != 0) & ~np.isfinite(known[:, None, :, 0])).any(-1)   # (N, n + 2)
    Du, Dk = D[:, 2:n + 2], D[:, kcols]
    w_acc = row_ok / sigma_acc[:, None] ** 2
    motion = np.einsum("ri,nr,rj->nij", Du, w_acc, Du)
    rhs = -np.einsum("ri,nr,rk,nkc->nic", Du, w_acc, Dk, np.nan_to_num(known))      # (N, n, 3)
    fixed = np.zeros((N, n, 3, 3))
    w_prior = np.zeros((N, n))
    if prior is not None and np.isfinite(sigma_prior):
        w_prior = np.isfinite(prior).all(-1) / sigma_prior ** 2                    # (N, n)
        prior = np.nan_to_num(prior)
        fixed += w_prior[..., None, None] * np.eye(3)
        rhs = rhs + w_prior[..., None] * prior
    else:
        prior = None
    bone = np.asarray(bone, float)
    w_bone = np.where(np.isfinite(bone), 1.0 / np.broadcast_to(np.asarray(sigma_bone, float), (N,)) ** 2, 0.0)
    gaps = _Gaps(motion, fixed, rhs, D, known, w_acc, np.nan_to_num(bone), w_bone, prior, w_prior)
    if ray_origin is not None and np.isfinite(sigma_ray):
        o, d = np.asarray(ray_origin, float), np.asarray(ray_direction, float)
        gaps.present = np.isfinite(o).all(-1) & np.isfinite(d).all(-1)            # (N, n, R)
        gaps.origin, gaps.direction = np.nan_to_num(o), np.nan_to_num(d)
        gaps.proj = np.eye(3) - gaps.direction[..., :, None] * gaps.direction[..., None, :]
        gaps.sigma_ray, gaps.gate = sigma_ray, gate
    return gaps


def _solve(gaps: _Gaps, per_instant: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The normal equations with the per-instant ``(N, n, 3, 3)`` terms: ``(H (N, 3n, 3n), r (N, n, 3))``."""
    N, n = rhs.shape[:2]
    H = (np.einsum("nts,cd->ntcsd", gaps.motion, np.eye(3))
         + np.einsum("ts,ntcd->ntcsd", np.eye(n), per_instant)).reshape(N, 3 * n, 3 * n)
    return H, np.linalg.solve(H, rhs.reshape(N, 3 * n, 1))[..., 0].reshape(N, n, 3)


def _ray_distances(gaps: _Gaps, r: np.ndarray) -> np.ndarray:
    """``(N, n, R)`` distances of the offsets ``r: (N, n, 3)`` to the rays."""
    return np.linalg.norm(np.einsum("ntrij,ntrj->ntri", gaps.proj, r[:, :, None] - gaps.origin), axis=-1)


def _descend(gaps: _Gaps, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton from ``r: (N, n, 3)``: the bone linearized about the current offsets, the rays
    re-weighted (Cauchy, a scale that narrows from the gate). ``(r, H, ray weights)``."""
    weight = np.zeros(r.shape[:2] + (0,))
    for k in range(ITERATIONS):
        norm = np.linalg.norm(r, axis=-1, keepdims=True)
        unit = np.where(norm > 0, r / np.maximum(norm, 1e-12), 0.0)                # (N, n, 3)
        wb = gaps.w_bone[:, None]
        per_instant = gaps.fixed + wb[..., None, None] * unit[..., :, None] * unit[..., None, :]
        rhs = gaps.rhs + wb[..., None] * unit * gaps.bone[:, None, None]
        if gaps.rays:
            distance = _ray_distances(gaps, r)
            scale = max(RAY_CAUCHY * gaps.sigma_ray, gaps.gate * 0.5 ** k)         # graduated: wide first
            weight = gaps.present * (distance <= gaps.gate) / (1.0 + (distance / scale) ** 2)
            w = weight / gaps.sigma_ray ** 2
            per_instant = per_instant + np.einsum("ntr,ntrij->ntij", w, gaps.proj)
            rhs = rhs + np.einsum("ntr,ntrij,ntrj->nti", w, gaps.proj, gaps.origin)
        H, r = _solve(gaps, per_instant, rhs)
    return r, H, weight


def _objective(gaps: _Gaps, r: np.ndarray) -> np.ndarray:
    """The objective at ``r: (N, n, 3)``, per gap ``(N,)`` (the rays' Cauchy loss at its final scale)."""
    known = np.nan_to_num(gaps.known)
    chain = np.concatenate([known[:, :2], r, known[:, 2:]], 1)                    # (N, n + 4, 3)
    total = (gaps.w_acc * (np.einsum("rk,nkc->nrc", gaps.D, chain) ** 2).sum(-1)).sum(1)
    total += gaps.w_bone * ((np.linalg.norm(r, axis=-1) - gaps.bone[:, None]) ** 2).sum(1)
    if gaps.prior is not None:
        total += (gaps.w_prior * ((r - gaps.prior) ** 2).sum(-1)).sum(1)
    if gaps.rays:
        s = RAY_CAUCHY * gaps.sigma_ray
        d = np.minimum(_ray_distances(gaps, r), gaps.gate)
        total += (gaps.present * s ** 2 * np.log1p((d / s) ** 2)).sum((1, 2)) / gaps.sigma_ray ** 2
    return total


def _other_meeting(gaps: _Gaps, start: np.ndarray) -> np.ndarray:
    """``start: (N, n, 3)`` moved, where a ray sees the joint, to the meeting of that ray with the
    bone's sphere farther from it (a depth the motion alone cannot tell); mirrored along the ray
    about its point nearest the parent where the ray misses the sphere or there is no bone."""
    first = np.argmax(gaps.present, -1)                                            # (N, n): a present ray
    o = np.take_along_axis(gaps.origin, first[..., None, None], 2)[:, :, 0]
    d = np.take_along_axis(gaps.direction, first[..., None, None], 2)[:, :, 0]
    along = ((start - o) * d).sum(-1)                                              # (N, n)
    foot = -(o * d).sum(-1)
    half = np.sqrt(np.maximum(foot ** 2 - (o ** 2).sum(-1) + gaps.bone[:, None] ** 2, 0.0))
    meets = (gaps.w_bone > 0)[:, None] & (half > 0)
    depth = np.where(meets, np.where(along > foot, foot - half, foot + half), 2 * foot - along)
    return np.where(gaps.present.any(-1)[..., None], o + depth[..., None] * d, start)


def _agreeing(gaps: _Gaps, start: np.ndarray, H: np.ndarray, gate_sigmas: np.ndarray) -> np.ndarray:
    """``(N, n, R)`` the present rays that agree with the guess ``start: (N, n, 3)`` of the
    motion and the prior (normal matrix ``H``). A ray agrees within ``gate_sigmas: (N,)``
    standard deviations of it (its posterior deviation and ``sigma_ray`` together). A view (the
    rays' last axis) with rays in the :data:`END_INSTANTS` instants next to a known side of the
    gap, where the guess is sharp, is kept or refused whole by them (at least half agree): a
    detector that reports another thing in a view does it through the stretch, and that view's
    rays jump off the joint's path where the gap begins; the other views ray by ray."""
    N, n = start.shape[:2]
    spread = np.sqrt(_variance(H, N, n) + gaps.sigma_ray ** 2)                    # (N, n)
    agree = gaps.present & (_ray_distances(gaps, start) <= gate_sigmas[:, None, None] * spread[..., None])
    t = np.arange(n)
    ends = (((t < END_INSTANTS) & np.isfinite(gaps.known[:, 1:2, 0]))
            | ((n - 1 - t < END_INSTANTS) & np.isfinite(gaps.known[:, 2:3, 0])))[..., None]   # (N, n, 1)
    tried = (gaps.present & ends).sum(1)                                           # (N, R)
    trusted = 2 * (agree & ends).sum(1) >= tried
    return np.where((tried > 0)[:, None], gaps.present & trusted[:, None], agree)


def _gated(gaps: _Gaps, start: np.ndarray, H: np.ndarray, gate_sigmas: np.ndarray) -> np.ndarray:
    """``(N, n, R)`` the rays :func:`_agreeing` keeps, the gate doubled up to
    :data:`GATE_DOUBLINGS` times for the gaps where it keeps none of them: the motion's guess
    understates its own error where the limb moved faster than the track's seen joints (a swing
    of 10 cm an instant), and a gate that refuses every view leaves the fill to that guess."""
    kept = _agreeing(gaps, start, H, gate_sigmas)
    for _ in range(GATE_DOUBLINGS):
        none = gaps.present.any((1, 2)) & ~kept.any((1, 2))                         # (N,)
        if not none.any():
            break
        gate_sigmas = np.where(none, 2 * gate_sigmas, gate_sigmas)
        kept = np.where(none[:, None, None], _agreeing(gaps, start, H, gate_sigmas), kept)
    return kept


def fit_gaps(before: np.ndarray, after: np.ndarray, bone: np.ndarray, sigma_acc: np.ndarray,
             sigma_bone: np.ndarray, prior: np.ndarray | None = None, sigma_prior: float = np.inf,
             ray_origin: np.ndarray | None = None, ray_direction: np.ndarray | None = None,
             sigma_ray: float = np.inf, gate: float = np.inf, gate_sigmas: np.ndarray | float = np.inf,
             prior_where_seen: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fill ``N`` gaps of ``n`` instants each.

    Args:
        before, after: ``(N, 2, 3)`` the known offsets at the two instants before the gap (older
            first) and the two after it; NaN where unknown (the nearest one known on one side
            at least: a gap at a track's end is continued from the other).
        bone: ``(N,)`` the bone's length (NaN: no bone term).
        sigma_acc: ``(N,)`` the standard deviation of the offset's second differences (> 0).
        sigma_bone: ``(N,)`` (or one number) the standard deviation of the bone's length.
        prior: ``(N, n, 3)`` the prior's offsets (NaN: none), ``sigma_prior`` their deviation.
        ray_origin, ray_direction: ``(N, n, R, 3)`` rays relative to the parent (origin: the
            camera centre minus the parent; direction: unit), NaN where absent; ``sigma_ray``
            the deviation of a point's distance to its ray; ``gate``: rays farther from the fit
            than this weigh nothing; ``gate_sigmas``: ``(N,)`` (or one number) rays farther
            than this many standard deviations from the guess of the motion and the prior
            alone (its posterior deviation and ``sigma_ray`` together) are refused before the
            fit: a keypoint that disagrees with where the track predicts the joint is another
            thing's.
        prior_where_seen: the prior's weight, relative to ``sigma_prior``'s, at the instants of
            the gaps whose rays were so tried (a finite ``gate_sigmas``) where a ray kept sees
            the joint: there the prior only picks the depth along the ray, and its guess, one
            for a slowly changing pose, is off alike at every instant of the gap.
    Returns:
        ``(r: (N, n, 3), std: (N, n), ray_weight: (N, n, R))``: the offsets, each instant's
        posterior standard deviation (per axis, the root mean of its covariance's diagonal)
        and the rays' final weights (0: refused; ``(N, n, 0)`` without rays).
    """
    before, after = np.asarray(before, float), np.asarray(after, float)
    N = len(before)
    if before.shape != (N, 2, 3) or after.shape != (N, 2, 3):
        raise ValueError(f"before, after: expected (N, 2, 3), got {before.shape} and {after.shape}")
    if not (np.isfinite(before[:, 1]).all(-1) | np.isfinite(after[:, 0]).all(-1)).all():
        raise ValueError("before, after: the offset next to a gap must be known on one side at least")
    n = next((np.shape(a)[1] for a in (prior, ray_origin) if a is not None), None)
    if n is None:
        raise ValueError("fit_gaps: the gap's length comes from prior or the rays; neither was given")
    sigma_acc = np.broadcast_to(np.asarray(sigma_acc, float), (N,))
    if not (sigma_acc > 0).all():
        raise ValueError(f"sigma_acc: must be > 0, got {sigma_acc.min()}")
    gaps = _gaps(before, after, bone, sigma_acc, sigma_bone, prior, sigma_prior, ray_origin, ray_direction,
                 sigma_ray, gate, n)
    H0, start = _solve(gaps, gaps.fixed + 1e-9 * np.eye(3), gaps.rhs)             # motion and prior only
    if gaps.rays and np.isfinite(gate_sigmas).any():
        gate_sigmas = np.broadcast_to(np.asarray(gate_sigmas, float), (N,))
        gaps.present = _gated(gaps, start, H0, gate_sigmas)
        if gaps.prior is not None and prior_where_seen != 1.0:
            _weigh_prior(gaps, gaps.present.any(-1) & np.isfinite(gate_sigmas)[:, None], prior_where_seen)
    r, H, weight = _descend(gaps, start)
    if gaps.rays:
        r2, H2, weight2 = _descend(gaps, _other_meeting(gaps, start))
        better = _objective(gaps, r2) < _objective(gaps, r)
        r, H, weight = (np.where(better[(...,) + (None,) * (a.ndim - 1)], b, a)
                        for a, b in ((r, r2), (H, H2), (weight, weight2)))
    return r, np.sqrt(np.maximum(_variance(H, N, n), 0.0)), weight


def _weigh_prior(gaps: _Gaps, where: np.ndarray, factor: float) -> None:
    """Multiply the prior's weights in the descent by ``factor`` at the instants ``where: (N, n)``
    of ``gaps`` (in place, the normal equations' prior terms). The objective that picks between
    the two descents (:func:`_objective`) keeps them whole: the prior's guess tells well which of
    the ray's two meetings with the bone's sphere is the joint, even where, off alike at every
    instant, it would draw the fill along the ray (on the simulated stretches of
    ``benchmarks/rig_occlusion.py``, wrists seen by one view over 40 instants were 30.6-30.7 mm
    off with it weighed less there too, 23.5-28.1 mm without)."""
    delta = gaps.w_prior * where * (factor - 1.0)                                  # (N, n)
    gaps.fixed = gaps.fixed + delta[..., None, None] * np.eye(3)
    gaps.rhs = gaps.rhs + delta[..., None] * gaps.prior


def _variance(H: np.ndarray, N: int, n: int) -> np.ndarray:
    """``(N, n)`` each instant's posterior variance per axis (the mean of its covariance's
    diagonal) from the normal matrices ``H: (N, 3n, 3n)``."""
    return np.einsum("nii->ni", np.linalg.inv(H)).reshape(N, n, 3).mean(-1)
