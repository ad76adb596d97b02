"""The affinity of two 2D poses (paper Eq. 1, 2): A = S · 1 / (1 + exp(γ D)).

Units of D. Eq. 2 averages point-to-epipolar-line distances over the joints both poses have.
The paper measures them in normalized image coordinates; here a distance measured in view
``u``'s pixels is divided by ``distance_scale · f_u`` (``f_u`` that view's focal length in
pixels). The unit is therefore a fixed *angle* (``distance_scale`` radians, 0.01 ≈ 0.57° by
default), the same for 640-px and 1920-px frames of the same lens, and γ is dimensionless.

With γ = 1 and distance_scale = 0.01, D = 0 gives A = 0.5 · S, an error of 1% of the focal
length gives 0.27 · S and 3% gives 0.05 · S.

The unit follows the detector's noise. A detector whose joints lie farther from the other views'
epipolar lines than the unit allows (a small model run on large frames: 20 px where 1 % of the focal
length is 17 px) would have its true matches refused. So each scene (each rig's capture) measures
its noise in that unit before the grouping, as the lower quartile of every pose's distance to the
nearest pose of every other view (:func:`unit_factor`), and divides D by how far that quartile
exceeds ``distance_quartile`` (at most :data:`MAX_NOISE_FACTOR`-fold): precise data keep the
unit of ``distance_scale``, and noisy data have it grown in proportion to their noise.
"""
from __future__ import annotations

import logging

import numpy as np

from mvm.core.config import Config
from mvm.core.geometry import cross, skew
from mvm.core.quality import row_nanmedian, row_nanquantile
from mvm.core.scene import Cameras, Poses2D

#: Working memory of one block of :func:`epipolar_distance` (bytes): the per-joint distances
#: of a block of pose pairs, ``17 × rows × columns`` numbers.
BLOCK_BYTES = 64 * 2**20

log = logging.getLogger(__name__)

#: The unit of D grows at most this many times with the measured noise (:func:`unit_factor`):
#: a capture whose nearest poses are mostly other people's cannot open its gate without bound.
MAX_NOISE_FACTOR = 4.0

#: A scene (a rig's capture) measures its noise from this many nearest-pose distances at least;
#: with fewer it keeps the unit of ``distance_scale``. [distances]
MIN_NOISE_SAMPLES = 6

#: The views of a scene, and the instants of a rig, whose poses measure the noise
#: (:func:`measured_unit_factor`): evenly spread, enough for a quartile at any length.
NOISE_VIEWS = 60
NOISE_INSTANTS = 200
#: At most this many of those poses (a frame of thousands of detections): the measure's memory
#: is bounded, ``NOISE_POSES²`` distances. [poses]
NOISE_POSES = 3000


def affinity_bytes(n_poses: int, appearance: bool, dtype=np.float32) -> int:
    """Peak memory of the affinity of ``n_poses`` 2D poses (:func:`pose_affinity`).

    The ``N × N`` distance matrix becomes the affinity matrix in place (``N² · 4`` bytes in
    float32); with appearance descriptors the ``N × N`` similarity S adds as much again. The
    rest is per view pair in blocks of at most :data:`BLOCK_BYTES`. So memory grows as
    ``4 N²`` bytes (``8 N²`` with appearance): 10,000 poses take 400 MB (800 MB).

    >>> affinity_bytes(10_000, appearance=False) - BLOCK_BYTES       # 4 N² bytes in float32
    400000000
    """
    item = np.dtype(dtype).itemsize
    return int(n_poses) ** 2 * item * (2 if appearance else 1) + BLOCK_BYTES


def _block_rows(columns: int, row_bytes_per_column: int, block_bytes: int) -> int:
    return max(1, block_bytes // max(1, columns * row_bytes_per_column))


def epipolar_distance(cameras: Cameras, keypoints: np.ndarray, view: np.ndarray,
                      keypoint_threshold: float, distance_scale: float,
                      min_common_keypoints: int = 1, dtype=np.float32,
                      block_bytes: int = BLOCK_BYTES, instant: np.ndarray | None = None) -> np.ndarray:
    """Geometric distance D (Eq. 2) of every pair of 2D poses.

    Args:
        cameras: the ``V`` views.
        keypoints: ``(N, 17, 3)`` x, y (pixels), confidence.
        view: ``(N,)`` view of each pose.
        keypoint_threshold: keypoints below this confidence are missing.
        distance_scale: the unit of D as a fraction of the focal length.
        min_common_keypoints: pairs sharing fewer keypoints get D = inf.
        block_bytes: working memory of one block (see below).
        instant: ``(N,)`` instant of each pose (a rig), or None: poses of different instants
            are never compared (D = inf), as poses of one view.
    Returns:
        ``D: (N, N)`` symmetric; ``inf`` for poses of the same view and for pairs whose
        distance overflows; NaN (undefined) for pairs of views with no baseline (no epipolar
        geometry) and pairs with too few common keypoints.

    Cost: for each view ``v`` with ``n_v`` poses, ``17 · n_v · (N − n_v)`` point-line
    distances (pairs within one view are never computed: they cannot match), i.e. at most
    ``O(17 · N²)`` multiply-adds in ``dtype``. Memory: the ``(N, N)`` result plus blocks of at
    most ``block_bytes`` (see :func:`affinity_bytes`), whatever the number of poses per view.
    """
    keypoints = np.asarray(keypoints, dtype=float)
    view = np.asarray(view)
    N = len(keypoints)
    item = np.dtype(dtype).itemsize
    sums = np.zeros((N, N), dtype=dtype)
    if N == 0:
        return sums
    visible, homogeneous = _homogeneous(keypoints, keypoint_threshold)

    used = np.unique(view)
    centers = cameras.centers
    no_baseline = _no_baseline(centers, used)

    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        plucker, M = _plucker_rays(cameras, homogeneous, view)
        unit = distance_scale * cameras.focal
        plucker = np.ascontiguousarray(plucker.transpose(1, 2, 0), dtype=dtype)         # (J, 6, N)
        M = M.astype(dtype)
        points = homogeneous.transpose(1, 0, 2).astype(dtype)                      # (J, N, 3)

        _one_sided_sums(sums, points, plucker, M, unit, view, used, block_bytes)
        _symmetrize(sums, visible.astype(dtype), view, instant, no_baseline, max(min_common_keypoints, 1),
                    max(1, int(np.sqrt(block_bytes / (4 * item)))))
    return sums


def _homogeneous(keypoints: np.ndarray, keypoint_threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """``keypoints: (N, J, 3)`` -> ``visible: (N, J)`` bool and homogeneous pixels ``(N, J, 3)``,
    zero where missing (a missing joint adds nothing to a distance)."""
    visible = keypoints[:, :, 2] >= max(keypoint_threshold, 1e-9)
    homogeneous = np.concatenate([keypoints[:, :, :2], np.ones(keypoints.shape[:2] + (1,))], axis=2)
    homogeneous[~visible] = 0.0
    return visible, homogeneous


def _unit_lines(lines: np.ndarray, unit: float) -> np.ndarray:
    """Epipolar lines ``(..., 3, n)`` scaled in place so that ``x · l`` is a distance in ``unit``
    (pixels per unit); ``l = 0`` stays 0."""
    lines *= (1.0 / unit) / (np.sqrt(lines[..., 0, :] ** 2 + lines[..., 1, :] ** 2) + 1e-30)[..., None, :]
    return lines


def _distance(total: np.ndarray, common: np.ndarray, min_common: int, undefined: np.ndarray,
              excluded: np.ndarray) -> np.ndarray:
    """D from the two one-sided sums ``total`` and the ``common`` keypoint counts (same shapes):
    ``total / (2 · common)``; inf on overflow and where ``excluded``, NaN where fewer than
    ``min_common`` keypoints are shared or ``undefined`` (no baseline)."""
    D = total / (2 * common)
    D[~np.isfinite(total)] = np.inf                                       # overflow: no match
    D[(common < min_common) | undefined] = np.nan
    D[excluded] = np.inf
    return D


def _one_sided_sums(sums: np.ndarray, points: np.ndarray, plucker: np.ndarray, M: np.ndarray, unit: np.ndarray,
                    view: np.ndarray, used: np.ndarray, block_bytes: int) -> None:
    """In place, ``sums[u, n]``: Σ_joints distance of x_u to the epipolar line of x_n, in
    view(u)'s unit, for poses of different views, one view against all others, in row blocks of
    at most ``block_bytes``. ``points: (J, N, 3)``, ``plucker: (J, 6, N)``, ``M: (V, 3, 6)``."""
    J = len(points)
    item = sums.dtype.itemsize
    for v in used:
        rows = np.flatnonzero(view == v)
        cols = np.flatnonzero(view != v)
        if len(cols) == 0:
            continue
        lines = _unit_lines(np.matmul(M[v], plucker[:, :, cols]), unit[v])     # (J, 3, n_c) in view v
        step = _block_rows(len(cols), J * item, block_bytes)
        for r0 in range(0, len(rows), step):
            chunk = rows[r0:r0 + step]
            d = np.matmul(points[:, chunk], lines)                              # (J, r, n_c)
            sums[chunk[:, None], cols] = np.abs(d, out=d).sum(axis=0)


def _plucker_rays(cameras: Cameras, homogeneous: np.ndarray, view: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every keypoint as a world ray in Plücker coordinates (moment m = C × b, direction b), and
    the matrices that map a ray to its epipolar line in a view: the line in view i is
    ``K_i^-T R_i (m − C_i × b) = M_i [m; b]``. ``homogeneous: (N, J, 3)``, ``view: (N,)`` ->
    ``plucker: (N, J, 6)``, ``M: (V, 3, 6)``."""
    centers = cameras.centers
    K_inv = np.linalg.inv(cameras.K)
    to_world = np.einsum("vba,vbc->vac", cameras.R, K_inv)                        # R^T K^-1: (V, 3, 3)
    b = np.matmul(homogeneous, to_world[view].transpose(0, 2, 1))                   # R^T K^-1 x: (N, J, 3)
    plucker = np.concatenate([cross(centers[view][:, None], b), b], axis=2)          # (N, J, 6)
    M = np.einsum("vba,vbc,vcd->vad", K_inv, cameras.R,
                  np.concatenate([np.broadcast_to(np.eye(3), (len(cameras), 3, 3)), -skew(centers)], axis=2))
    return plucker, M


def _no_baseline(centers: np.ndarray, used: np.ndarray) -> np.ndarray:
    """``(V, V)`` bool: pairs of the ``used`` views whose centres coincide (no epipolar geometry),
    relative to the median distance between the used centres. ``centers: (V, 3)``."""
    baseline = np.linalg.norm(centers[used][:, None] - centers[used][None], axis=-1)
    scale = row_nanmedian(baseline.reshape(1, -1))[0] if len(used) > 1 else 1.0
    no_baseline = np.zeros((len(centers), len(centers)), dtype=bool)
    no_baseline[np.ix_(used, used)] = baseline <= 1e-9 * max(scale, 1e-12)
    return no_baseline


def _symmetrize(sums: np.ndarray, visible: np.ndarray, view: np.ndarray, instant: np.ndarray | None,
                no_baseline: np.ndarray,
                min_common: int, step: int) -> None:
    """In place, ``step × step`` block pair by block pair: ``D = (s + sᵀ) / (2 · common)`` from the
    one-sided sums ``sums: (N, N)``; ``inf`` on overflow, within a view and across instants, NaN where fewer than
    ``min_common`` keypoints are shared or the views have no baseline. ``visible: (N, J)``."""
    N = len(sums)
    for i0 in range(0, N, step):
        i = slice(i0, min(i0 + step, N))
        for j0 in range(i0, N, step):
            j = slice(j0, min(j0 + step, N))
            excluded = view[i][:, None] == view[j][None, :]
            if instant is not None:
                excluded |= instant[i][:, None] != instant[j][None, :]
            D = _distance(sums[i, j] + sums[j, i].T, visible[i] @ visible[j].T, min_common,
                          no_baseline[view[i][:, None], view[j][None, :]], excluded)
            sums[i, j] = D
            sums[j, i] = D.T


def block_epipolar_distance(cameras: Cameras, keypoints: np.ndarray, view: np.ndarray, blocks: np.ndarray,
                            keypoint_threshold: float, distance_scale: float, min_common_keypoints: int = 1,
                            dtype=np.float32) -> np.ndarray:
    """D (Eq. 2) within each of ``B`` small blocks of poses (the instants of a rig), all blocks
    at once: :func:`epipolar_distance` of each block's poses, without the pairs across blocks.

    ``keypoints: (N, 17, 3)``, ``view: (N,)``; ``blocks: (B, n)`` pose indices, -1 for padding
    -> ``D: (B, n, n)`` (inf for padding). Memory: ``B · 17 · n²`` numbers of ``dtype``.
    """
    keypoints = np.asarray(keypoints, dtype=float)
    view = np.asarray(view)
    blocks = np.asarray(blocks)
    present = blocks >= 0
    idx = np.where(present, blocks, 0)
    visible, homogeneous = _homogeneous(keypoints, keypoint_threshold)
    visible = (visible[idx] & present[..., None]).astype(dtype)                # (B, n, J)
    v_of = np.where(present, view[idx], -1)                                     # (B, n)
    used = np.unique(v_of[present])
    sums = np.zeros(blocks.shape + blocks.shape[-1:], dtype=dtype)             # (B, n, n)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        plucker, M = _plucker_rays(cameras, homogeneous, view)
        unit = distance_scale * cameras.focal
        rays = np.ascontiguousarray(plucker[idx].transpose(0, 2, 3, 1), dtype=dtype)   # (B, J, 6, n)
        points = homogeneous[idx].transpose(0, 2, 1, 3).astype(dtype)                 # (B, J, n, 3)
        for v in used:
            lines = _unit_lines(np.matmul(M[v].astype(dtype), rays), unit[v])         # (B, J, 3, n)
            d = np.matmul(points, lines)                                               # (B, J, n, n)
            np.copyto(sums, np.abs(d, out=d).sum(axis=1), where=(v_of == v)[:, :, None])
        no_baseline = _no_baseline(cameras.centers, used)
        pad_view = np.where(present, v_of, 0)
        excluded = (v_of[:, :, None] == v_of[:, None, :]) | ~present[:, :, None] | ~present[:, None, :]
        return _distance(sums + sums.transpose(0, 2, 1), visible @ visible.transpose(0, 2, 1),
                         max(min_common_keypoints, 1), no_baseline[pad_view[:, :, None], pad_view[:, None, :]],
                         excluded)


def appearance_similarity(appearance: np.ndarray | None, n: int, dtype=np.float32) -> np.ndarray | float:
    """Cosine similarity S of appearance descriptors, clipped to [0, 1].

    ``appearance: (N, D)`` or None -> ``(N, N)``, or the scalar 1.0 when descriptors are absent.
    Non-finite descriptors count as absent (similarity 0).
    """
    if appearance is None:
        return 1.0
    a = np.asarray(appearance, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        a = np.where(np.isfinite(a).all(axis=1, keepdims=True), a, 0.0)
        norm = np.linalg.norm(a, axis=1, keepdims=True)
        a = np.where(norm > 0, a / np.maximum(norm, 1e-300), 0.0)
        a = np.where(np.isfinite(a), a, 0.0).astype(dtype)
    S = a @ a.T
    return np.clip(S, 0.0, 1.0, out=S)


def affinity(D: np.ndarray, gamma: float, S: np.ndarray | float = 1.0,
             out: np.ndarray | None = None) -> np.ndarray:
    """Eq. 1: ``A = S / (1 + exp(γ D))``. ``D: (N, N)`` -> ``A: (N, N)`` in [0, 0.5]; D = inf
    gives 0 and an undefined D (NaN) stays NaN. ``out=D`` computes it in place (no second
    ``N × N`` matrix)."""
    with np.errstate(over="ignore", invalid="ignore"):
        A = np.multiply(D, gamma, out=out)
        np.minimum(A, 80.0, out=A)
        np.exp(A, out=A)
        A += 1.0
        np.reciprocal(A, out=A)
    if np.isscalar(S):
        if S != 1.0:
            A *= S
        return A
    A *= S
    return A


def nearest_in_views(D: np.ndarray, view: np.ndarray) -> np.ndarray:
    """Each pose's smallest D to the poses of every view.

    ``D: (..., R, n)`` distances of ``R`` poses to ``n`` poses (inf or NaN: no match), ``view:
    (..., n)`` the view of each of the ``n`` (-1: padding) -> ``(..., R, V)`` for the ``V`` views
    present, NaN where a view has no pose within reach (the pose's own view among them).

    >>> D = np.array([[np.inf, 0.3, 0.9, 2.0], [0.3, np.inf, 0.5, np.nan]])
    >>> nearest_in_views(D, np.array([0, 1, 2, 2])).tolist()
    [[nan, 0.3, 0.9], [0.3, nan, 0.5]]
    """
    D = np.where(np.isnan(D), np.inf, D)
    used = np.unique(view[view >= 0])
    if not len(used):
        return np.full(D.shape[:-1] + (0,), np.nan)
    if view.ndim == 1:                                   # one set of columns: sorted by view, reduced by runs
        order = np.argsort(view, kind="stable")
        order = order[view[order] >= 0]
        start = np.flatnonzero(np.r_[True, np.diff(view[order]) != 0])
        nearest = np.minimum.reduceat(D[..., order], start, axis=-1)
    else:                                                # blocks of their own views: one view at a time
        nearest = np.stack([np.where(view[..., None, :] == v, D, np.inf).min(-1) for v in used], axis=-1)
    return np.where(np.isfinite(nearest), nearest, np.nan)


def unit_factor(nearest: np.ndarray, quartile: float) -> np.ndarray:
    """How many times the unit of D must grow for the detector's noise: the lower quartile of
    the nearest-pose distances of each scene (:func:`nearest_in_views`), over ``quartile``,
    within ``[1, MAX_NOISE_FACTOR]``; 1 where fewer than :data:`MIN_NOISE_SAMPLES` were measured
    or ``quartile`` is 0.

    The nearest pose of another view is, for most poses, the same person seen there, at a
    distance that is the detector's noise (mapped through the two views' geometry); a person
    unseen there gives a larger distance, a neighbour on the same epipolar line a smaller one, so
    the lower quartile measures the noise while up to three in four nearest poses are another
    person's.

    ``nearest: (B, K)`` distances of ``B`` scenes (NaN: none) -> ``(B,)``.

    >>> unit_factor(np.array([[0.1] * 8, [0.8] * 8, [0.8] * 3 + [np.nan] * 5, [9.0] * 8]), 0.4).tolist()
    [1.0, 2.0, 1.0, 4.0]
    """
    nearest = np.asarray(nearest, dtype=float)
    if quartile <= 0 or nearest.shape[-1] == 0:
        return np.ones(nearest.shape[0])
    measured = row_nanquantile(nearest, 0.25)
    enough = (~np.isnan(nearest)).sum(-1) >= MIN_NOISE_SAMPLES
    return np.where(enough, np.clip(measured / quartile, 1.0, MAX_NOISE_FACTOR), 1.0)


def _spread(values: np.ndarray, count: int) -> np.ndarray:
    """At most ``count`` of the sorted unique ``values``, evenly spread over them."""
    values = np.unique(values)
    return values[np.unique(np.linspace(0, len(values) - 1, min(len(values), count)).round().astype(np.int64))] \
        if len(values) else values


def measured_unit_factor(cameras: Cameras, poses: Poses2D, config: Config) -> float:
    """:func:`unit_factor` of a scene or of a rig's capture, measured once for all its poses: on
    the poses of at most :data:`NOISE_VIEWS` evenly spread views of a scene (at most
    :data:`NOISE_POSES` of them), or of at most
    :data:`NOISE_INSTANTS` evenly spread instants of a rig (the nearest poses of every instant's
    poses pooled: the detector's noise is the capture's, not one instant's, and an instant of
    few poses, most of them false, cannot open the gate for itself)."""
    if config.distance_quartile <= 0 or not len(poses):
        return 1.0
    if poses.instant is None:
        rows = np.flatnonzero(np.isin(poses.view, _spread(poses.view, NOISE_VIEWS)))
        sub = poses.subset(rows[_spread(np.arange(len(rows)), NOISE_POSES)])
        D = epipolar_distance(cameras, sub.keypoints, sub.view, config.keypoint_threshold, config.distance_scale,
                              config.min_common_keypoints)
        nearest = nearest_in_views(D, sub.view)
    else:
        chosen = _spread(poses.instant, NOISE_INSTANTS)
        rows = np.flatnonzero(np.isin(poses.instant, chosen))
        which = np.searchsorted(chosen, poses.instant[rows])
        order = np.lexsort((rows, which))
        rows, which = rows[order], which[order]
        slot = np.arange(len(rows)) - np.searchsorted(which, which)
        blocks = np.full((len(chosen), int(slot.max()) + 1), -1)
        blocks[which, slot] = rows
        D = block_epipolar_distance(cameras, poses.keypoints, poses.view, blocks, config.keypoint_threshold,
                                    config.distance_scale, config.min_common_keypoints)
        nearest = nearest_in_views(D, np.where(blocks >= 0, poses.view[np.maximum(blocks, 0)], -1))
    return float(unit_factor(nearest.reshape(1, -1), config.distance_quartile)[0])


def with_measured_unit(cameras: Cameras, poses: Poses2D, config: Config) -> Config:
    """``config`` whose ``distance_scale`` includes the noise of ``poses``
    (:func:`measured_unit_factor`), measured once: ``distance_quartile`` becomes 0."""
    if config.distance_quartile <= 0:
        return config
    factor = measured_unit_factor(cameras, poses, config)
    log.info("the unit of the epipolar distance: %.3g of the focal length (the measured noise: x%.2f)",
             config.distance_scale * factor, factor)
    return config.replace(distance_scale=config.distance_scale * factor, distance_quartile=0.0)


def pose_affinity(cameras: Cameras, poses: Poses2D, config: Config, appearance: bool | None = None) -> np.ndarray:
    """Eq. 1 and 2 for every pair of ``poses`` (a scene, or instants of a rig).

    ``A: (N, N)`` float32 in [0, 0.5], NaN where D is undefined, 0 across instants. ``appearance``: multiply by
    the appearance similarity S (default ``config.use_appearance``; ignored without descriptors).
    Memory: see :func:`affinity_bytes` (D becomes A in place).
    """
    use_appearance = config.use_appearance if appearance is None else appearance
    D = epipolar_distance(cameras, poses.keypoints, poses.view, config.keypoint_threshold,
                          config.distance_scale, config.min_common_keypoints, instant=poses.instant)
    S = appearance_similarity(poses.appearance if use_appearance else None, len(poses))
    return affinity(D, config.gamma, S, out=D)


def block_pose_affinity(cameras: Cameras, poses: Poses2D, blocks: np.ndarray, config: Config) -> np.ndarray:
    """:func:`pose_affinity` within each of ``B`` blocks of ``poses``: ``blocks: (B, n)`` pose
    indices, -1 for padding -> ``A: (B, n, n)`` float32 (0 for padding). See
    :func:`block_epipolar_distance`."""
    D = block_epipolar_distance(cameras, poses.keypoints, poses.view, blocks, config.keypoint_threshold,
                                config.distance_scale, config.min_common_keypoints)
    S = appearance_similarity(poses.appearance if config.use_appearance else None, len(poses))
    if not np.isscalar(S):
        idx = np.maximum(blocks, 0)
        S = S[idx[:, :, None], idx[:, None, :]]
    return affinity(D, config.gamma, S, out=D)


def mse_distance(keypoints: np.ndarray, view: np.ndarray, keypoint_threshold: float,
                 focal: np.ndarray, distance_scale: float, min_common_keypoints: int = 1) -> np.ndarray:
    """The paper's MSE baseline distance: mean squared 2D distance of common keypoints, in the
    same unit as :func:`epipolar_distance` (squared, then square-rooted). ``(N, N)``."""
    visible = keypoints[:, :, 2] >= max(keypoint_threshold, 1e-9)
    xy = keypoints[:, :, :2] / (distance_scale * focal[view])[:, None, None]
    xy = np.where(visible[..., None], xy, 0.0)
    sq = (xy**2).sum(-1)
    common = visible.astype(float) @ visible.T.astype(float)
    cross = np.einsum("ujd,vjd->uv", xy, xy)
    total = sq @ visible.T.astype(float) + visible.astype(float) @ sq.T - 2 * cross
    with np.errstate(divide="ignore", invalid="ignore"):
        D = np.sqrt(np.maximum(total, 0) / common)
    D[common < max(min_common_keypoints, 1)] = np.nan
    D[view[:, None] == view[None, :]] = np.inf
    return D
