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
- **prior**: the offset the pose prior expects from the rest of the body, ``sigma_prior``.

The posterior standard deviation of each filled instant (the inverse of the normal matrix)
grows towards the middle of a gap and with its length, and shrinks where a ray sees the joint.
Arrays in, arrays out; no I/O. Units: those of the arrays (metres in the rig driver's calls).
"""
from __future__ import annotations

import numpy as np

#: Gauss-Newton iterations (bone linearization, ray weights).
ITERATIONS = 6
#: A ray's Cauchy weight halves at this many ``sigma_ray`` from the fit. [1]
RAY_CAUCHY = 3.0


def second_differences(n: int) -> np.ndarray:
    """``(n + 2, n + 4)``: the second differences of a chain of ``n + 4`` values (two known ones
    before a gap of ``n``, two after)."""
    D = np.zeros((n + 2, n + 4))
    i = np.arange(n + 2)
    D[i, i], D[i, i + 1], D[i, i + 2] = 1.0, -2.0, 1.0
    return D


def fit_gaps(before: np.ndarray, after: np.ndarray, bone: np.ndarray, sigma_acc: np.ndarray,
             sigma_bone: np.ndarray, prior: np.ndarray | None = None, sigma_prior: float = np.inf,
             ray_origin: np.ndarray | None = None, ray_direction: np.ndarray | None = None,
             sigma_ray: float = np.inf, gate: float = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
            than this weigh nothing.
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
    # Motion: H_acc (N, n, n) shared by the 3 axes; rows touching an unknown known are dropped.
    D = second_differences(n)
    known = np.concatenate([before, after], 1)                                     # (N, 4, 3)
    kcols = np.array([0, 1, n + 2, n + 3])
    row_ok = ~((D[None][:, :, kcols] != 0) & ~np.isfinite(known[:, None, :, 0])).any(-1)   # (N, n + 2)
    Du, Dk = D[:, 2:n + 2], D[:, kcols]
    w_acc = row_ok / sigma_acc[:, None] ** 2                                       # (N, n + 2)
    H_acc = np.einsum("ri,nr,rj->nij", Du, w_acc, Du)
    g_acc = -np.einsum("ri,nr,rk,nkc->nic", Du, w_acc, Dk, np.nan_to_num(known))  # (N, n, 3)
    eye = np.eye(3)
    B = np.zeros((N, n, 3, 3))                                                     # per-instant 3x3 terms
    g_fix = g_acc.copy()
    if prior is not None and np.isfinite(sigma_prior):
        has = np.isfinite(prior).all(-1)
        B += has[..., None, None] * eye / sigma_prior ** 2
        g_fix += np.where(has[..., None], np.nan_to_num(prior), 0.0) / sigma_prior ** 2
    rays = ray_origin is not None and np.isfinite(sigma_ray)
    if rays:
        o, d = np.asarray(ray_origin, float), np.asarray(ray_direction, float)
        present = np.isfinite(o).all(-1) & np.isfinite(d).all(-1)                  # (N, n, R)
        o, d = np.nan_to_num(o), np.nan_to_num(d)
        proj = eye - d[..., :, None] * d[..., None, :]                            # (N, n, R, 3, 3)
        proj_o = np.einsum("ntrij,ntrj->ntri", proj, o)
    bone = np.asarray(bone, float)
    sigma_bone = np.broadcast_to(np.asarray(sigma_bone, float), (N,))
    has_bone = np.isfinite(bone)

    def solve(B_total, g_total):
        H = (np.einsum("nts,cd->ntcsd", H_acc, eye)
             + np.einsum("ts,ntcd->ntcsd", np.eye(n), B_total)).reshape(N, 3 * n, 3 * n)
        return H, np.linalg.solve(H, g_total.reshape(N, 3 * n, 1))[..., 0].reshape(N, n, 3)

    def ray_distances(r):                                                          # (N, n, R)
        return np.linalg.norm(np.einsum("ntrij,ntj->ntri", proj, r) - proj_o, axis=-1)

    def descend(r):
        """Gauss-Newton from ``r``: ``(r, H, ray weights, cost (N,))``."""
        weight = np.zeros((N, n, 0))
        for k in range(ITERATIONS):
            B_k, g_k = B.copy(), g_fix.copy()
            norm = np.linalg.norm(r, axis=-1, keepdims=True)
            unit = np.where(norm > 0, r / np.maximum(norm, 1e-12), 0.0)            # (N, n, 3)
            B_k += wb[..., None, None] * unit[..., :, None] * unit[..., None, :]
            g_k += wb[..., None] * unit * np.nan_to_num(bone)[:, None, None]
            if rays:
                distance = ray_distances(r)
                scale = max(RAY_CAUCHY * sigma_ray, gate * 0.5 ** k)            # graduated: wide first
                weight = present * (distance <= gate) / (1.0 + (distance / scale) ** 2)
                w = weight / sigma_ray ** 2
                B_k += np.einsum("ntr,ntrij->ntij", w, proj)
                g_k += np.einsum("ntr,ntri->nti", w, proj_o)
            H, r = solve(B_k, g_k)
        return r, H, weight, cost(r)

    def cost(r):
        """The objective at ``r``, per gap: ``(N,)``."""
        chain = np.concatenate([np.nan_to_num(known[:, :2]), r, np.nan_to_num(known[:, 2:])], 1)   # (N, n + 4, 3)
        total = (w_acc * (np.einsum("rk,nkc->nrc", D, chain) ** 2).sum(-1)).sum(1)
        total += (wb[:, 0] * ((np.linalg.norm(r, axis=-1) - np.nan_to_num(bone)[:, None]) ** 2).sum(1))
        if prior is not None and np.isfinite(sigma_prior):
            total += np.nansum(((r - prior) ** 2).sum(-1), 1) / sigma_prior ** 2
        if rays:
            s = RAY_CAUCHY * sigma_ray
            d = np.minimum(ray_distances(r), gate)
            total += (present * s ** 2 * np.log1p((d / s) ** 2)).sum((1, 2)) / sigma_ray ** 2
        return total

    wb = np.where(has_bone, 1.0 / sigma_bone ** 2, 0.0)[:, None]                  # (N, 1)
    _, start = solve(B + 1e-9 * eye, g_fix)                                        # motion and prior only
    r, H, weight, best = descend(start)
    if rays:
        # The other meeting of a view's ray with the bone's sphere: of the two, the one farther
        # from the start (a depth the motion alone cannot tell); the start mirrored about the
        # ray's point nearest the parent where the ray misses the sphere or there is no bone.
        first = np.argmax(present, -1)                                             # (N, n): a present ray
        seen = present.any(-1)
        o1 = np.take_along_axis(o, first[..., None, None], 2)[:, :, 0]
        d1 = np.take_along_axis(d, first[..., None, None], 2)[:, :, 0]
        along = ((start - o1) * d1).sum(-1)                                        # (N, n)
        foot = -(o1 * d1).sum(-1)
        half = np.sqrt(np.maximum(foot ** 2 - (o1 ** 2).sum(-1) + np.nan_to_num(bone)[:, None] ** 2, 0.0))
        meets = has_bone[:, None] & (half > 0)
        far = np.where(along > foot, foot - half, foot + half)
        depth = np.where(meets, far, 2 * foot - along)
        mirrored = np.where(seen[..., None], o1 + depth[..., None] * d1, start)
        r2, H2, weight2, cost2 = descend(mirrored)
        better = cost2 < best
        r, H, weight = (np.where(better[(...,) + (None,) * (a.ndim - 1)], b, a)
                        for a, b in ((r, r2), (H, H2), (weight, weight2)))
    cov = np.linalg.inv(H)
    var = np.einsum("nii->ni", cov).reshape(N, n, 3).mean(-1)
    return r, np.sqrt(np.maximum(var, 0.0)), weight
