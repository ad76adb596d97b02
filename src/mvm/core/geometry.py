"""Multi-view geometry on batched arrays: projection, DLT triangulation. Pure numpy, no I/O.

Conventions: world -> camera ``x_cam = R X + t``; projection matrices ``P = K [R | t]``;
pixel coordinates of an undistorted pinhole camera.
"""
from __future__ import annotations

import numpy as np


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a × b`` of ``(..., 3)`` vectors (broadcast), the numbers of ``np.cross`` without its
    per-call overhead, which dominates on the small arrays of one scene.

    >>> cross(np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    array([0., 0., 1.])
    """
    return a[..., [1, 2, 0]] * b[..., [2, 0, 1]] - a[..., [2, 0, 1]] * b[..., [1, 2, 0]]


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices. ``v: (..., 3)`` -> ``(..., 3, 3)`` with ``skew(a) @ b == a × b``.

    >>> a, b = np.array([1.0, 2.0, 3.0]), np.array([-1.0, 0.5, 2.0])
    >>> np.allclose(skew(a) @ b, np.cross(a, b))
    True
    """
    v = np.asarray(v, dtype=float)
    zero = np.zeros(v.shape[:-1])
    return np.stack([
        np.stack([zero, -v[..., 2], v[..., 1]], -1),
        np.stack([v[..., 2], zero, -v[..., 0]], -1),
        np.stack([-v[..., 1], v[..., 0], zero], -1),
    ], -2)


def project(points: np.ndarray, P: np.ndarray, min_depth: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Project world points through pinhole cameras: the one projection of mvm (every other,
    lens included, comes down to it; :mod:`mvm.core.camera` builds ``P`` and adds the lens).

    Args:
        points: ``(..., N, 3)`` world coordinates (NaN: missing): each camera's block of ``N``
            points; ``(3,)`` a single point.
        P: ``(..., 3, 4)`` projection matrices ``K [R | t]``; the leading axes broadcast against
            those of ``points`` (``points: (Q, 1, J, 3)`` with ``P: (F, 3, 4)``: every person in
            every view, ``(Q, F, J, ...)``).
        min_depth: with ``> 0``, depths nearer zero than this divide as ``min_depth`` (a finite
            pixel for every finite point, as a solver needs); ``0``: a plain division.
    Returns:
        pixels ``(..., N, 2)`` and depths ``(..., N)``: camera z, <= 0 behind the camera.

    >>> P = np.hstack([np.eye(3), np.zeros((3, 1))])
    >>> project(np.array([2.0, 4.0, 2.0]), P)[0]
    array([1., 2.])
    >>> project(np.zeros((5, 1, 17, 3)) + [0, 0, 1], np.stack([P] * 4))[0].shape
    (5, 4, 17, 2)
    """
    points = np.asarray(points, dtype=float)
    homogeneous = np.concatenate([points, np.ones(points.shape[:-1] + (1,))], axis=-1)
    x = homogeneous @ np.swapaxes(np.asarray(P, dtype=float), -1, -2)            # (..., N, 3)
    depth = x[..., 2]
    divisor = np.where(np.abs(depth) > min_depth, depth, min_depth) if min_depth > 0 else depth
    with np.errstate(divide="ignore", invalid="ignore"):
        pixels = x[..., :2] / divisor[..., None]
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
    rows /= np.maximum(np.sqrt((rows * rows).sum(-1, keepdims=True)), 1e-12)
    a, b = rows[..., 0, :], rows[..., 1, :]                                     # (..., M, 4) each
    terms = np.empty((10,) + rows.shape[:-2])
    other = np.empty(rows.shape[:-2])
    for k, (i, j) in enumerate(PACKED_4X4):                                     # written in place, term by term
        np.multiply(a[..., i], a[..., j], out=terms[k])
        terms[k] += np.multiply(b[..., i], b[..., j], out=other)
    return terms


#: The 2 × 2 minors of rows 0, 1 (``s``) and rows 2, 3 (``c``) of a 4 × 4 matrix, by column
#: pair ``(i, j)``: ``m[r][i] m[r + 1][j] − m[r + 1][i] m[r][j]``, in this order (the names
#: below index them): s01 s02 s03 s12 s13 s23, then c23 c13 c12 c03 c02.
_MINOR_COLUMNS = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3), (2, 3), (1, 3), (1, 2), (0, 3), (0, 2)])
_MINOR_ROW = np.array([0] * 6 + [2] * 5)
S0, S1, S2, S3, S4, S5, C5, C4, C3, C2, C1 = range(11)

#: The upper triangle of the adjugate, entry ``(i, j)`` as ``sign · (m_a q_a − m_b q_b + m_c q_c)``
#: with ``m_*`` entries (row, column) of the matrix and ``q_*`` minors (Laplace expansion by
#: complementary minors).
_ADJUGATE = (
    ((0, 0), +1, ((1, 1), C5), ((1, 2), C4), ((1, 3), C3)),
    ((0, 1), -1, ((0, 1), C5), ((0, 2), C4), ((0, 3), C3)),
    ((0, 2), +1, ((3, 1), S5), ((3, 2), S4), ((3, 3), S3)),
    ((0, 3), -1, ((2, 1), S5), ((2, 2), S4), ((2, 3), S3)),
    ((1, 1), +1, ((0, 0), C5), ((0, 2), C2), ((0, 3), C1)),
    ((1, 2), -1, ((3, 0), S5), ((3, 2), S2), ((3, 3), S1)),
    ((1, 3), +1, ((2, 0), S5), ((2, 2), S2), ((2, 3), S1)),
    ((2, 2), +1, ((3, 0), S4), ((3, 1), S2), ((3, 3), S0)),
    ((2, 3), -1, ((2, 0), S4), ((2, 1), S2), ((2, 3), S0)),
    ((3, 3), +1, ((2, 0), S3), ((2, 1), S1), ((2, 2), S0)),
)
_ADJ_SIGN = np.array([sign for _, sign, *_ in _ADJUGATE], dtype=float)
_ADJ_ENTRY = np.array([[4 * i + j for (i, j), _ in terms] for _, _, *terms in _ADJUGATE]).T     # (3, 10)
_ADJ_MINOR = np.array([[q for _, q in terms] for _, _, *terms in _ADJUGATE]).T                  # (3, 10)
#: Packed index (:data:`PACKED_4X4`) of each of the 16 entries of a symmetric 4 × 4 matrix.
_UNPACK = np.array([[PACKED_4X4.index((min(i, j), max(i, j))) for j in range(4)] for i in range(4)]).ravel()


def _adjugate(m: np.ndarray) -> np.ndarray:
    """Adjugate of symmetric 4 × 4 matrices ``m: (16, ...)`` (entry ``4 i + j`` first) ->
    ``(16, ...)``, by 2 × 2 minors, every minor and every entry of the upper triangle in one
    step each (mirrored below)."""
    rows = 4 * _MINOR_ROW[:, None] + _MINOR_COLUMNS                          # (11, 2)
    minors = m[rows[:, 0]] * m[rows[:, 1] + 4] - m[rows[:, 0] + 4] * m[rows[:, 1]]   # (11, ...)
    e, q = _ADJ_ENTRY, _ADJ_MINOR
    upper = m[e[0]] * minors[q[0]] - m[e[1]] * minors[q[1]] + m[e[2]] * minors[q[2]]   # (10, ...)
    upper *= _ADJ_SIGN.reshape((10,) + (1,) * (m.ndim - 1))
    return upper[_UNPACK]


def _matvec(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``m: (16, ...)`` 4 × 4 matrices times ``v: (4, ...)`` vectors -> ``(4, ...)``, the four
    products of each row summed in column order."""
    m = m.reshape((4, 4) + m.shape[1:])
    out = m[:, 0] * v[0]
    for j in range(1, 4):
        out += m[:, j] * v[j]
    return out


def _sum4(x: np.ndarray) -> np.ndarray:
    """``x[0] + x[1] + x[2] + x[3]``, in that order."""
    return x[0] + x[1] + x[2] + x[3]


def _normalized(v: np.ndarray) -> np.ndarray:
    norm = np.sqrt(_sum4(v * v))
    with np.errstate(divide="ignore", invalid="ignore"):
        return v / norm


#: Entries ``(i, i)``, ``(j, j)`` and ``(i, j)`` of the pairs ``i < j`` of a 4 × 4 matrix ``(16, ...)``.
_PAIR_II = np.array([0, 0, 0, 5, 5, 10])
_PAIR_JJ = np.array([5, 10, 15, 10, 15, 15])
_PAIR_IJ = np.array([1, 2, 3, 6, 7, 11])


def _power_null_vector(m: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Smallest eigenvector of the symmetric PSD matrices ``m: (16, ...)`` (entries scaled to
    trace 1) by power iteration on the adjugate, whose eigenvalues are ``λ₂λ₃λ₄ >= λ₁λ₃λ₄ >= …``
    (same eigenvectors): each step shrinks the error by ``λ₁ / λ₂``. Returns the unit vector
    ``(4, ...)`` and ``ok``: the Davis–Kahan bound ``‖N v − ρ v‖ / (λ₂ − ρ)`` is below
    :data:`NULL_VECTOR_TOLERANCE`, with ``λ₂ >= e₃' / e₂'`` from the elementary symmetric
    functions of ``λ₂, λ₃, λ₄``."""
    adj = _adjugate(m)
    diagonal = adj[[0, 5, 10, 15]]
    start = np.argmax(diagonal, axis=0)                                      # the largest column of adj
    v = np.take_along_axis(adj.reshape((4, 4) + adj.shape[1:]), start[None, None], axis=1)[:, 0]
    for _ in range(iterations):
        v = _normalized(_matvec(adj, v))
    Nv = _matvec(m, v)
    rho = _sum4(v * Nv)
    r = Nv - rho * v
    residual = np.sqrt(_sum4(r * r))
    e1 = _sum4(m[[0, 5, 10, 15]])
    off = m[_PAIR_IJ]
    minors = m[_PAIR_II] * m[_PAIR_JJ] - off * off                          # (6, ...)
    e2 = 0.0 + minors[0]
    for k in range(1, 6):
        e2 += minors[k]
    e3 = _sum4(diagonal)
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
    flat = packed.reshape(10, -1)
    vectors = np.empty((flat.shape[1], 4))
    for start in range(0, flat.shape[1], NULL_VECTOR_CHUNK):
        vectors[start:start + NULL_VECTOR_CHUNK] = _smallest_eigenvectors(flat[:, start:start + NULL_VECTOR_CHUNK],
                                                                          iterations)
    return vectors.reshape(packed.shape[1:] + (4,))


#: :func:`smallest_eigenvector` solves this many matrices at a time: its temporaries (about a
#: hundred per matrix) then stay in cache, whatever the batch.
NULL_VECTOR_CHUNK = 2**14


def _smallest_eigenvectors(packed: np.ndarray, iterations: int) -> np.ndarray:
    """:func:`smallest_eigenvector` of ``packed: (10, n)`` -> ``(n, 4)``."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        scale = packed[0] + packed[4] + packed[7] + packed[9]
        unit = packed / np.where(scale > 0, scale, 1.0)
        v, ok = _power_null_vector(unit[_UNPACK], iterations)
    vectors = v.T
    bad = ~ok
    if bad.any():
        chosen = np.moveaxis(packed[:, bad][_UNPACK].reshape(4, 4, -1), 2, 0)     # (b, 4, 4)
        finite = np.isfinite(chosen).all(axis=(-2, -1))
        fixed = np.full(chosen.shape[:-1], np.nan)
        if finite.any():
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

    Two cameras one unit apart along x, both looking along z:

    >>> P = np.array([np.hstack([np.eye(3), [[0.0], [0.0], [0.0]]]), np.hstack([np.eye(3), [[-1.0], [0.0], [0.0]]])])
    >>> X = np.array([0.5, 0.2, 4.0])
    >>> uv, _ = project(X, P)
    >>> triangulate_dlt(uv, P).round(9)
    array([0.5, 0.2, 4. ])
    >>> triangulate_dlt(uv, P, np.array([1.0, 0.0]))                  # one view left: no point
    array([nan, nan, nan])
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

    >>> rays = np.array([[1.0, 0, 0], [0, 1, 0], [np.sqrt(0.5), np.sqrt(0.5), 0]])
    >>> float(ray_spread_deg(rays, np.array([True, True, True])).round(9))
    90.0
    >>> float(ray_spread_deg(rays, np.array([True, False, False])))       # one ray: no parallax
    0.0
    """
    d = np.where(mask[..., None], directions, 0.0)
    mean = d.sum(axis=-2)
    mean /= np.maximum(np.linalg.norm(mean, axis=-1, keepdims=True), 1e-12)
    cos_mean = np.where(mask, (d * mean[..., None, :]).sum(-1), 2.0)
    far = np.take_along_axis(d, np.argmin(cos_mean, axis=-1)[..., None, None], axis=-2)  # (..., 1, 3)
    cos = np.where(mask, (d * far).sum(-1), 1.0)
    return np.degrees(np.arccos(np.minimum(np.maximum(cos.min(axis=-1), -1.0), 1.0)))


def view_spread(points: np.ndarray, centers: np.ndarray, used: np.ndarray) -> np.ndarray:
    """How well a point's views constrain it in every direction: the smallest eigenvalue of the
    mean over its views of ``I − d dᵀ`` (``d`` the unit ray from the camera centre to the point;
    the sum is the normal matrix of triangulating the point from its rays). 2/3 for views spread
    evenly over a sphere, 1/2 evenly around a circle (a camera ring, a dome), about ``θ²/3`` for
    views along an arc of ``±θ`` radians (a hand-held tour), 0 for views along one line.

    ``points: (P, 3)``, ``centers: (P, M, 3)`` camera centres, ``used: (P, M)`` bool -> ``(P,)``,
    NaN for a point that is not finite or has fewer than two views.

    >>> ring = np.array([[[np.cos(a), np.sin(a), 0.0] for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)]])
    >>> round(float(view_spread(np.zeros((1, 3)), ring, np.ones((1, 8), bool))[0]), 3)
    0.5
    """
    d = points[:, None, :] - centers                                               # (P, M, 3)
    d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
    d = np.where((used & np.isfinite(d).all(-1))[..., None], d, 0.0)
    n = (np.abs(d).sum(-1) > 0).sum(-1)                                            # (P,)
    normal = n[:, None, None] * np.eye(3) - np.einsum("pmi,pmj->pij", d, d)
    smallest = np.linalg.eigvalsh(normal)[:, 0] / np.maximum(n, 1)
    return np.where((n >= 2) & np.isfinite(points).all(-1), smallest, np.nan)


def similarity_transform(source: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None,
                         scale: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares similarity ``target ≈ s R source + t`` (Umeyama), batched.

    ``source, target: (..., N, 3)``; ``mask: (..., N)`` the points of the fit (default: finite
    in both) -> ``s: (...)``, ``R: (..., 3, 3)``, ``t: (..., 3)`` (``s = 1`` without ``scale``).

    >>> source = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> Rz = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])          # 90° about z
    >>> s, R, t = similarity_transform(source, 2.0 * source @ Rz.T + [1.0, 2.0, 3.0])
    >>> round(float(s), 9), np.allclose(R, Rz), t.round(9)
    (2.0, True, array([1., 2., 3.]))
    """
    source, target = np.asarray(source, dtype=float), np.asarray(target, dtype=float)
    if source.shape != target.shape or source.ndim < 2 or source.shape[-1] != 3:
        raise ValueError(f"similarity_transform: expected two (..., N, 3) arrays, got {source.shape} and "
                         f"{target.shape}")
    if mask is None:
        mask = np.isfinite(source).all(-1) & np.isfinite(target).all(-1)
    w = np.asarray(mask, dtype=float)[..., None]                                  # (..., N, 1)
    n = np.maximum(w.sum(-2, keepdims=True), 1)
    A, B = np.nan_to_num(source), np.nan_to_num(target)
    mu_a, mu_b = (w * A).sum(-2, keepdims=True) / n, (w * B).sum(-2, keepdims=True) / n
    A0, B0 = (A - mu_a) * w, (B - mu_b) * w
    U, S, Vt = np.linalg.svd(np.einsum("...ji,...jk->...ik", B0, A0))            # B0ᵀ A0 = U S Vt
    D = np.ones_like(S)
    D[..., -1] = np.sign(np.linalg.det(U @ Vt))
    R = (U * D[..., None, :]) @ Vt
    s = (S * D).sum(-1) / np.maximum((A0 ** 2).sum((-2, -1)), 1e-12) if scale else np.ones(S.shape[:-1])
    t = mu_b[..., 0, :] - s[..., None] * np.einsum("...ij,...j->...i", R, mu_a[..., 0, :])
    return s, R, t
