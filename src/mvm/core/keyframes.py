"""Keyframes and windows of a long video: the views on which the grouping (Algorithm 1) runs.

A frozen scene filmed for two minutes holds no more people than one filmed for ten seconds:
most frames add views of persons already found. The grouping compares every pair of poses it
is given (``O(N²)`` time and memory), so on a long video it runs on a bounded set of
well-spread *keyframes* only; the association consistent in 3D
(:mod:`mvm.core.association`) then brings every other frame's poses in by reprojection, at a
cost linear in the poses. The poses no person explains are grouped within *windows* of
consecutive frames, each bounded, so a person the keyframes missed is still found.

Arrays: ``V`` views, ``F <= V`` of them with poses. Pure numpy, no I/O.
"""
from __future__ import annotations

import numpy as np


def spread_views(views: np.ndarray, count: int, sequence: np.ndarray | None, centers: np.ndarray) -> np.ndarray:
    """At most ``count`` of ``views`` (``(F,)`` distinct view indices), well spread, sorted.

    With a video ``sequence`` (``(V,)`` position of every view), evenly spaced along the video
    (the first and the last frame included): on a camera tour, evenly spread in position and
    direction. Without one (unordered photos), farthest-point sampling of the camera
    ``centers: (V, 3)``, from the view farthest from their mean. All of ``views`` when they are
    ``count`` or fewer.

    >>> spread_views(np.arange(10), 3, np.arange(10), None)          # along a video: both ends and the middle
    array([0, 4, 9])
    >>> centers = np.array([[0.0, 0, 0], [0.1, 0, 0], [5, 0, 0], [5.1, 0, 0]])
    >>> spread_views(np.arange(4), 2, None, centers)                  # unordered photos: far apart
    array([0, 3])
    """
    views = np.unique(np.asarray(views, dtype=np.int64))
    if len(views) <= count:
        return views
    if sequence is not None:
        ordered = views[np.argsort(np.asarray(sequence)[views], kind="stable")]
        return np.unique(ordered[np.round(np.linspace(0, len(ordered) - 1, count)).astype(np.int64)])
    c = np.asarray(centers, dtype=float)[views]
    chosen = np.zeros(len(views), dtype=bool)
    distance = np.linalg.norm(c - c.mean(0), axis=1)
    for _ in range(count):                                  # count steps, each over the F views
        best = int(np.argmax(np.where(chosen, -np.inf, distance)))
        chosen[best] = True
        distance = np.minimum(distance, np.linalg.norm(c - c[best], axis=1))
    return views[chosen]


def frame_windows(view: np.ndarray, size: int, sequence: np.ndarray | None) -> np.ndarray:
    """Window of each pose: consecutive runs of ``size`` of the views that hold poses, in video
    order (``sequence: (V,)``, or view order without one). ``view: (N,)`` -> ``(N,)`` int,
    0 for every pose when the poses span ``size`` views or fewer.

    >>> frame_windows(np.array([0, 0, 1, 2, 3, 4, 5]), 2, None)
    array([0, 0, 0, 1, 1, 2, 2])
    >>> frame_windows(np.array([3, 1]), 2, np.array([0, 9, 0, 1]))   # view 3 comes before view 1 in the video
    array([0, 0])
    """
    view = np.asarray(view, dtype=np.int64)
    used, inverse = np.unique(view, return_inverse=True)
    rank = np.empty(len(used), dtype=np.int64)
    rank[np.argsort(np.asarray(sequence)[used] if sequence is not None else used, kind="stable")] = np.arange(len(used))
    return rank[inverse] // max(int(size), 1)
