"""The distance of 2D poses to the reprojection of 3D persons, for candidate (pose, person) pairs.

Distances are those of OKS: pixels divided by the person's image size, ``s = sqrt(w h)`` of
the bounding box of its reprojected joints, so one gate serves every distance and resolution.
The distance of a pose is the median over its joints, so a few wrong joints do not move it, and
a pose detected left-right swapped is measured swapped back. Persons are projected, and pairs
measured, a few at a time (:data:`PAIRS_CHUNK`): the temporaries stay a few MB at any length of
video, beside the projections themselves (``Q · F · J`` points, in proportion to the video).
The association consistent in 3D (:mod:`mvm.core.association`) assigns by these distances.

Arrays: ``N`` 2D poses, ``J = 17`` joints, ``F`` views, ``Q`` persons, ``K`` pairs.
"""
from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from mvm.core.geometry import project
from mvm.core.keypoints import FLIP_PERMUTATION


def reprojection_cost(keypoints: np.ndarray, frame: np.ndarray, P: np.ndarray, X: np.ndarray,
                      pose: np.ndarray, person: np.ndarray, keypoint_threshold: float,
                      min_common_keypoints: int, swap_above: float = 0.0,
                      max_cost: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Normalized distance of 2D poses to the reprojection of 3D persons, for candidate pairs.

    The distance of a pose is the median, over the joints both observed and reconstructed, of
    the keypoint's distance to the reprojected joint divided by the person's image size: a few
    wrong joints do not move it. A pose detected left-right swapped is measured swapped back
    (tried where the distance as detected is at least ``swap_above``).

    Args:
        keypoints, frame: ``(N, J, 3)`` pixels and confidence, ``(N,)`` view of each pose.
        P, X: ``(F, 3, 4)`` projection matrices, ``(Q, J, 3)`` persons (NaN: not reconstructed).
        pose, person: ``(K,)`` candidate pairs (indices into ``keypoints`` and ``X``).
        keypoint_threshold, min_common_keypoints: a keypoint of lower confidence is missing;
            with fewer joints both observed and reconstructed, the cost is inf.
        max_cost: costs at least this large are inf (a caller that reads no larger cost is
            spared sorting the distances of the pairs that cannot match).
    Returns:
        ``cost: (K,)`` in person sizes (inf where undefined), and ``size: (K,)`` the person's
        image size ``sqrt(w h)`` of its reprojected joints' bounding box, px.

    >>> P = np.hstack([np.eye(3), [[0], [0], [1.0]]])[None]          # one camera at z = -1
    >>> X = np.zeros((1, 17, 3)); X[0, :, 0] = np.linspace(0, 1, 17); X[0, :, 1] = X[0, :, 0]
    >>> kp = np.concatenate([X[0, :, :2] + [0.1, 0], np.ones((17, 1))], 1)[None]
    >>> cost, size = reprojection_cost(kp, np.array([0]), P, X, np.array([0]), np.array([0]), 0.2, 3)
    >>> round(float(cost[0]), 3), float(size[0])
    (0.1, 1.0)
    """
    K = len(pose)
    if K == 0:
        return np.zeros(0), np.zeros(0)
    # Project every person into every view used (Q·F·J points, far fewer than pairs·J).
    frames, frame_of_pair = _used(frame[pose], len(P))
    persons, person_of_pair = _used(person, len(X))
    uv_all, seen_all, size_all, centre_all = _projections(X[persons], P[frames])
    # A pose whose keypoints' centre lies more than 1.5 person sizes from the reprojection's
    # centre (half a body even when only the upper or lower half is detected) cannot have half
    # its joints within a fraction of a size of it: such pairs are skipped.
    observed = keypoints[..., 2] >= keypoint_threshold                                   # (N, J)
    centre = np.where(observed[..., None], keypoints[..., :2], 0).sum(1) / np.maximum(observed.sum(1), 1)[:, None]
    size = size_all[person_of_pair, frame_of_pair]
    near = np.flatnonzero(np.linalg.norm(centre[pose] - centre_all[person_of_pair, frame_of_pair], axis=-1)
                          < 1.5 * size)
    cost = np.full(K, np.inf)
    for start in range(0, len(near), PAIRS_CHUNK):
        rows = near[start:start + PAIRS_CHUNK]
        cost[rows] = _median_distance(keypoints[pose[rows]], uv_all[person_of_pair[rows], frame_of_pair[rows]],
                                      seen_all[person_of_pair[rows], frame_of_pair[rows]], size[rows],
                                      keypoint_threshold, min_common_keypoints, swap_above, max_cost)
    return cost, np.where(np.isfinite(cost), size, np.nan)


#: Pairs whose keypoint distances are measured at once: a few MB per array, whatever the length of
#: the video (arrays beyond the allocator's reuse threshold, 32 MB, cost their page faults anew
#: at every call, more than the arithmetic on them).
PAIRS_CHUNK = 2**14


def person_chunks(Q: int, F: int) -> Iterator[slice]:
    """Slices of ``Q`` persons to project into ``F`` views a few at a time: under
    :data:`PAIRS_CHUNK` person-views each, so that the projections' arrays stay a few MB."""
    step = max(1, PAIRS_CHUNK // max(F, 1))
    return (slice(s, s + step) for s in range(0, Q, step))


def project_in_views(X: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Persons ``X: (q, J, 3)`` (NaN: not reconstructed) in views ``P: (F, 3, 4)``
    (:func:`mvm.core.geometry.project`): pixels ``uv: (q, F, J, 2)`` and ``seen: (q, F, J)``,
    finite and in front of the camera. Callers give it a few persons at a time
    (:func:`person_chunks`)."""
    uv, depth = project(X[:, None], P[None])
    return uv, np.isfinite(uv).all(-1) & (depth > 0)


def _projections(X: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Persons ``X: (Q, J, 3)`` in views ``P: (F, 3, 4)``: pixels ``uv: (Q, F, J, 2)``, ``seen: (Q, F, J)``
    (:func:`project_in_views`), the person's image size ``sqrt(w h)`` of the bounding box of its
    seen joints ``(Q, F)`` and their centre ``(Q, F, 2)``."""
    Q, J, F = len(X), X.shape[1], len(P)
    uv, seen = np.empty((Q, F, J, 2)), np.empty((Q, F, J), dtype=bool)
    size, centre = np.empty((Q, F)), np.empty((Q, F, 2))
    for rows in person_chunks(Q, F):
        uv[rows], seen[rows] = project_in_views(X[rows], P)
        u, s = uv[rows], seen[rows, ..., None]
        lo = np.where(s, u, np.inf).min(2)
        hi = np.where(s, u, -np.inf).max(2)
        size[rows] = np.sqrt(np.prod(np.maximum(hi - lo, 1.0), axis=-1))
        centre[rows] = np.where(s, u, 0).sum(2) / np.maximum(seen[rows].sum(2), 1)[..., None]
    return uv, seen, size, centre


def _used(index: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(index, return_inverse=True)`` of indices ``(K,)`` into ``size`` items, by a
    table of the items used (no sort): the used items, increasing, and each entry's rank among them."""
    used = np.zeros(size, dtype=bool)
    used[index] = True
    rank = np.cumsum(used) - 1
    return np.flatnonzero(used), rank[index]


def _median_distance(kp: np.ndarray, uv: np.ndarray, seen: np.ndarray, size: np.ndarray,
                     keypoint_threshold: float, min_common_keypoints: int, swap_above: float,
                     max_cost: float = np.inf) -> np.ndarray:
    """Median normalized keypoint distance, the pose as detected or, where that is at least
    ``swap_above``, left-right swapped back if that is closer; inf where at least ``max_cost``.
    ``kp: (K, J, 3)``, ``uv: (K, J, 2)``, ``seen: (K, J)``, ``size: (K,)`` -> ``(K,)``."""
    xy, observed = kp[..., :2], kp[..., 2] >= keypoint_threshold
    cost = _median(xy, uv, seen & observed, size, min_common_keypoints, max_cost)
    # Swapped back only where the pose as detected does not fit (a swap then shows).
    far = np.flatnonzero(cost >= swap_above)
    swapped = _median(xy[far][:, FLIP_PERMUTATION], uv[far], seen[far] & observed[far][:, FLIP_PERMUTATION],
                      size[far], min_common_keypoints, max_cost)
    cost[far] = np.fmin(cost[far], swapped)
    return cost


def _median(xy: np.ndarray, uv: np.ndarray, common: np.ndarray, size: np.ndarray, min_common: int,
            max_cost: float = np.inf) -> np.ndarray:
    """Median over the ``common: (K, J)`` joints of the distance of ``xy`` to ``uv`` (``(K, J, 2)``)
    in sizes ``size: (K,)``; inf with fewer than ``min_common`` joints, or where it is at least
    ``max_cost``: fewer than half the joints closer than that, found by counting, so that only
    the pairs that may match are sorted. The distances are taken coordinate by coordinate and
    sorted in float32 (a reduction over a last axis of two and a sort in float64 cost twice as much)."""
    with np.errstate(invalid="ignore"):
        d = xy - uv
        d *= d
        distance = np.where(common, np.sqrt(d[..., 0] + d[..., 1]) / size[:, None], np.inf).astype(np.float32)
    n = np.count_nonzero(common, axis=1)
    rank = np.maximum((n - 1) // 2, 0)                                      # the lower median's
    out = np.full(len(n), np.inf)
    may = np.flatnonzero((n >= min_common) & (np.count_nonzero(distance < max_cost, axis=1) > rank))
    distance = np.sort(distance[may], axis=1)
    out[may] = distance[np.arange(len(may)), rank[may]]
    return out
