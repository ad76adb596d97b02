"""Multi-view geometry on batched arrays: projection, DLT triangulation. Pure numpy, no I/O.

Conventions: world -> camera ``x_cam = R X + t``; projection matrices ``P = K [R | t]``;
pixel coordinates of an undistorted pinhole camera.
"""
from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices. ``v: (..., 3)`` -> ``(..., 3, 3)`` with ``skew(a) @ b == a × b``."""
    v = np.asarray(v, dtype=float)
    zero = np.zeros(v.shape[:-1])
    return np.stack([
        np.stack([zero, -v[..., 2], v[..., 1]], -1),
        np.stack([v[..., 2], zero, -v[..., 0]], -1),
        np.stack([-v[..., 1], v[..., 0], zero], -1),
    ], -2)


def project(points: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points. ``points: (..., 3)``, ``P: (..., 3, 4)`` (broadcast) ->
    pixels ``(..., 2)`` and depths ``(..., )`` (camera z; <= 0 is behind the camera).

    >>> P = np.hstack([np.eye(3), np.zeros((3, 1))])
    >>> project(np.array([2.0, 4.0, 2.0]), P)[0]
    array([1., 2.])
    """
    points = np.asarray(points, dtype=float)
    homogeneous = np.concatenate([points, np.ones(points.shape[:-1] + (1,))], axis=-1)
    x = np.einsum("...ij,...j->...i", P, homogeneous)
    depth = x[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        pixels = x[..., :2] / depth[..., None]
    return pixels, depth


#: Upper-triangle entries of a symmetric 4 × 4 matrix in the packed layout ``(10, ...)``:
#: ``00 01 02 03 11 12 13 22 23 33``.
PACKED_4X4 = ((0, 0), (0, 1), (0, 2), (0, 3), (1, 1), (1, 2), (1, 3), (2, 2), (2, 3), (3, 3))

#: A null vector is accepted when its Davis–Kahan bound on the angle to the true eigenvector
#: (Rayleigh residual over a lower bound of the eigen-gap) is below this, in radians; the
#: others are solved by ``np.linalg.eigh``.
NULL_VECTOR_TOLERANCE = 1e-9


def dlt_terms(points: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Each view's contribution to the DLT normal matrix, packed (see :data:`PACKED_4X4`).

    ``points: (..., M, 2)``, ``P: (..., M, 3, 4)`` -> ``(10, ..., M)``: ``a aᵀ + b bᵀ`` of the view's
    two unit-norm rows ``a = x p₃ - p₁``, ``b = y p₃ - p₂``. The normal matrix of weights ``w`` is
    ``Σ_m w_m² terms[..., m]``; of a pair of views, the sum of their two terms.
    """
    points = np.asarray(points, dtype=float)
    P = np.asarray(P, dtype=float)
    rows = points[..., :, None] * P[..., 2:3, :] - P[..., :2, :]                # (..., M, 2, 4)
    rows = rows / np.maximum(np.sqrt((rows * rows).sum(-1, keepdims=True)), 1e-12)
    rows = np.ascontiguousarray(np.moveaxis(rows, (-2, -1), (0, 1)))           # (2, 4, ..., M)
    return np.stack([(rows[:, i] * rows[:, j]).sum(0) for i, j in PACKED_4X4])


def _adjugate(m: list) -> list:
    """Adjugate of symmetric 4 × 4 matrices given as the 16 entries ``m[i][j]`` (arrays), by
    2 × 2 minors: ``adj[i][j]`` (symmetric; only ``j >= i`` are computed, mirrored)."""
    s0, s1, s2 = m[0][0] * m[1][1] - m[1][0] * m[0][1], m[0][0] * m[1][2] - m[1][0] * m[0][2], \
        m[0][0] * m[1][3] - m[1][0] * m[0][3]
    s3, s4, s5 = m[0][1] * m[1][2] - m[1][1] * m[0][2], m[0][1] * m[1][3] - m[1][1] * m[0][3], \
        m[0][2] * m[1][3] - m[1][2] * m[0][3]
    c5, c4, c3 = m[2][2] * m[3][3] - m[3][2] * m[2][3], m[2][1] * m[3][3] - m[3][1] * m[2][3], \
        m[2][1] * m[3][2] - m[3][1] * m[2][2]
    c2, c1 = m[2][0] * m[3][3] - m[3][0] * m[2][3], m[2][0] * m[3][2] - m[3][0] * m[2][2]
    a = [[None] * 4 for _ in range(4)]
    a[0][0] = m[1][1] * c5 - m[1][2] * c4 + m[1][3] * c3
    a[0][1] = -m[0][1] * c5 + m[0][2] * c4 - m[0][3] * c3
    a[0][2] = m[3][1] * s5 - m[3][2] * s4 + m[3][3] * s3
    a[0][3] = -m[2][1] * s5 + m[2][2] * s4 - m[2][3] * s3
    a[1][1] = m[0][0] * c5 - m[0][2] * c2 + m[0][3] * c1
    a[1][2] = -m[3][0] * s5 + m[3][2] * s2 - m[3][3] * s1
    a[1][3] = m[2][0] * s5 - m[2][2] * s2 + m[2][3] * s1
    a[2][2] = m[3][0] * s4 - m[3][1] * s2 + m[3][3] * s0
    a[2][3] = -m[2][0] * s4 + m[2][1] * s2 - m[2][3] * s0
    a[3][3] = m[2][0] * s3 - m[2][1] * s1 + m[2][2] * s0
    for i in range(4):
        for j in range(i):
            a[i][j] = a[j][i]
    return a


def _matvec(m: list, v: list) -> list:
    return [m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2] + m[i][3] * v[3] for i in range(4)]


def _normalized(v: list) -> list:
    norm = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3])
    with np.errstate(divide="ignore", invalid="ignore"):
        return [c / norm for c in v]


def _power_null_vector(m: list, iterations: int) -> tuple[list, np.ndarray]:
    """Smallest eigenvector of the symmetric PSD matrices ``m[i][j]`` (entries scaled to trace 1)
    by power iteration on the adjugate, whose eigenvalues are ``λ₂λ₃λ₄ >= λ₁λ₃λ₄ >= …`` (same
    eigenvectors): each step shrinks the error by ``λ₁ / λ₂``. Returns the unit vector (4 arrays)
    and ``ok``: the Davis–Kahan bound ``‖N v − ρ v‖ / (λ₂ − ρ)`` is below :data:`NULL_VECTOR_TOLERANCE`,
    with ``λ₂ >= e₃' / e₂'`` from the elementary symmetric functions of ``λ₂, λ₃, λ₄``."""
    adj = _adjugate(m)
    diagonal = np.stack([adj[i][i] for i in range(4)])
    start = np.argmax(diagonal, axis=0)                                      # the largest column of adj
    v = [np.choose(start, adj[i]) for i in range(4)]
    for _ in range(iterations):
        v = _normalized(_matvec(adj, v))
    Nv = _matvec(m, v)
    rho = sum(v[i] * Nv[i] for i in range(4))
    residual = np.sqrt(sum((Nv[i] - rho * v[i]) ** 2 for i in range(4)))
    e1 = m[0][0] + m[1][1] + m[2][2] + m[3][3]
    e2 = sum(m[i][i] * m[j][j] - m[i][j] * m[i][j] for i in range(4) for j in range(i + 1, 4))
    e3 = diagonal.sum(0)
    e1r = e1 - rho
    e2r = e2 - rho * e1r
    e3r = e3 - rho * e2r
    with np.errstate(divide="ignore", invalid="ignore"):
        gap = e3r / e2r - rho
        ok = (gap > 0) & (residual <= NULL_VECTOR_TOLERANCE * gap)
    return v, ok


def smallest_eigenvector(packed: np.ndarray, iterations: int = 2) -> np.ndarray:
    """Unit eigenvector of the smallest eigenvalue of symmetric positive semi-definite 4 × 4
    matrices (the null vector of a DLT), batched and elementwise.

    ``packed: (10, ...)`` upper triangles (:data:`PACKED_4X4`) -> ``(..., 4)``, sign arbitrary.
    Power iteration on the adjugate (:func:`_power_null_vector`, about 5× faster than
    ``eigh`` on many small matrices): a vector is kept where it is certified within
    :data:`NULL_VECTOR_TOLERANCE` radians of the exact eigenvector; the others (a nearly
    repeated smallest eigenvalue, rank < 3) are ``np.linalg.eigh``'s, and NaN where the matrix
    is not finite.

    >>> N = np.diag([3.0, 1e-9, 2.0, 1.0])
    >>> np.abs(smallest_eigenvector(np.stack([N[i, j] for i, j in PACKED_4X4]))).round(6)
    array([0., 1., 0., 0.])
    """
    packed = np.asarray(packed, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        scale = packed[0] + packed[4] + packed[7] + packed[9]
        unit = packed / np.where(scale > 0, scale, 1.0)
        m = [[None] * 4 for _ in range(4)]
        for k, (i, j) in enumerate(PACKED_4X4):
            m[i][j] = m[j][i] = unit[k]
        v, ok = _power_null_vector(m, iterations)
    vectors = np.stack(v, axis=-1)
    bad = ~ok
    if bad.any():
        full = np.empty(packed.shape[1:] + (4, 4))
        for k, (i, j) in enumerate(PACKED_4X4):
            full[..., i, j] = full[..., j, i] = packed[k]
        chosen = full[bad]
        finite = np.isfinite(chosen).all(axis=(-2, -1))
        fixed = np.full(chosen.shape[:-1], np.nan)
        fixed[finite] = np.linalg.eigh(chosen[finite])[1][..., :, 0]
        vectors[bad] = fixed
    return vectors


def triangulate_dlt(points: np.ndarray, P: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Weighted linear (DLT) triangulation, batched.

    Args:
        points: ``(..., M, 2)`` observations of one point in ``M`` views.
        P: ``(..., M, 3, 4)`` projection matrices.
        weights: ``(..., M)`` non-negative weights; 0 drops a view. Default 1.
    Returns:
        ``(..., 3)`` points minimizing the weighted algebraic error (NaN where fewer than two
        views have weight).

    For conditioning, pass normalized coordinates (``K^-1 x`` with ``[R | t]``) where the
    intrinsics are large; the result is the same point.
    """
    points = np.asarray(points, dtype=float)
    weights = np.ones(points.shape[:-1]) if weights is None else np.asarray(weights, dtype=float)
    return weighted_dlt(dlt_terms(points, P), weights)


def weighted_dlt(terms: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """:func:`triangulate_dlt` from the views' :func:`dlt_terms` ``(10, ..., M)`` and ``weights:
    (..., M)`` -> ``(..., 3)``, NaN where fewer than two views have weight."""
    enough = (weights > 0).sum(axis=-1) >= 2
    return solve_dlt(np.einsum("k...m,...m->k...", terms, weights**2), enough)


def solve_dlt(normal: np.ndarray, keep: np.ndarray | bool = True) -> np.ndarray:
    """The point of packed DLT normal matrices ``(10, ...)`` -> ``(..., 3)``, NaN at infinity
    and where ``keep`` is False."""
    keep = np.asarray(keep)
    X = smallest_eigenvector(np.where(keep, normal, np.nan) if keep.ndim else normal)   # NaN: not solved
    with np.errstate(divide="ignore", invalid="ignore"):
        result = X[..., :3] / X[..., 3:4]
    return np.where(keep[..., None], result, np.nan)


def ray_spread_deg(directions: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Parallax of a bundle of rays, in degrees: the largest angle between the masked ray
    farthest from the bundle's mean direction and any other masked ray (a two-sweep estimate
    of the largest pairwise angle: exact on an arc, never below half of it).

    ``directions: (..., M, 3)`` unit vectors, ``mask: (..., M)`` bool -> ``(...)`` (0 with < 2 rays).
    """
    d = np.where(mask[..., None], directions, 0.0)
    mean = d.sum(axis=-2)
    mean /= np.maximum(np.linalg.norm(mean, axis=-1, keepdims=True), 1e-12)
    cos_mean = np.where(mask, (d * mean[..., None, :]).sum(-1), 2.0)
    far = np.take_along_axis(d, np.argmin(cos_mean, axis=-1)[..., None, None], axis=-2)  # (..., 1, 3)
    cos = np.where(mask, (d * far).sum(-1), 1.0)
    return np.degrees(np.arccos(np.clip(cos.min(axis=-1), -1.0, 1.0)))
