"""The unit of image distances in the reconstruction: the size of the people in the image.

A detector's keypoint error grows with the person's size in the image (the camera's resolution,
its distance to the people, the detector), so the reconstruction measures every image distance
it thresholds or weighs in person sizes: pixels divided by the median, over the people detected
in that view, of ``s = sqrt(w h)`` of the box of their keypoints (the scale of OKS, and of the
association, :mod:`mvm.core.association`). The median over a view's people rather than each
person's own box: a box shrinks with the joints a detection misses (occlusion, the frame's
border) and grows with an outlier joint, while the detector's error does neither; and within a
view, people at similar distances share one threshold in pixels. The same scene with its image
coordinates and intrinsics scaled by any factor then gives the same persons and 3D poses.

Arrays: ``N`` 2D poses, ``P`` persons, ``M`` view slots, ``J`` joints.
"""
from __future__ import annotations

import numpy as np

#: The smallest person size (a pose of one keypoint has no box). [px]
MIN_SIZE_PX = 1.0


def person_sizes(xy: np.ndarray, present: np.ndarray) -> np.ndarray:
    """``sqrt(w h)`` of the box of the present keypoints, at least :data:`MIN_SIZE_PX` (also
    where none is present). ``xy: (..., J, 2)`` px, ``present: (..., J)`` bool -> ``(...)`` px.

    >>> xy = np.array([[[0.0, 0.0], [30.0, 120.0], [5.0, 5.0]]])
    >>> person_sizes(xy, np.array([[True, True, False]])).tolist()
    [60.0]
    """
    lo = np.where(present[..., None], xy, np.inf).min(-2)
    hi = np.where(present[..., None], xy, -np.inf).max(-2)
    with np.errstate(invalid="ignore"):
        side = np.where(present.any(-1)[..., None], hi - lo, 0.0)
    return np.sqrt(np.prod(np.maximum(side, MIN_SIZE_PX), axis=-1))


def view_sizes(poses, keypoint_threshold: float) -> np.ndarray:
    """``(N,)`` the unit of each 2D pose's view, px: the median :func:`person_sizes` of the
    poses detected in the same view (and instant, for a rig), over their keypoints of confidence
    ``keypoint_threshold`` or more. ``poses``: a :class:`mvm.core.scene.Poses2D`."""
    keypoints = poses.keypoints
    sizes = person_sizes(keypoints[..., :2], keypoints[..., 2] >= keypoint_threshold)
    view = np.asarray(poses.view, dtype=np.int64)
    if poses.instant is not None:
        view = view + (int(view.max(initial=0)) + 1) * np.unique(poses.instant, return_inverse=True)[1].reshape(-1)
    key, label = np.unique(view, return_inverse=True)
    return medians_by(sizes, label.reshape(-1), len(key))[label.reshape(-1)]


def medians_by(values: np.ndarray, labels: np.ndarray, count: int) -> np.ndarray:
    """The median of ``values: (K,)`` with each label of ``labels: (K,)`` in ``[0, count)``,
    one sort for all -> ``(count,)``, NaN for a label without values.

    >>> medians_by(np.array([3.0, 1.0, 2.0, 10.0, 4.0]), np.array([0, 0, 0, 2, 2]), 3).tolist()
    [2.0, nan, 7.0]
    """
    counts = np.bincount(labels, minlength=count)
    if not len(values):
        return np.full(count, np.nan)
    order = np.lexsort((values, labels))
    ordered = values[order]
    start = np.cumsum(counts) - counts
    last = len(values) - 1
    lo = ordered[np.minimum(start + (counts - 1) // 2, last)]
    hi = ordered[np.minimum(start + counts // 2, last)]
    return np.where(counts > 0, (lo + hi) / 2, np.nan)


def in_person_sizes(xy: np.ndarray, P: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints and projections whose image coordinates are in person sizes: ``xy / s`` and
    ``diag(1/s, 1/s, 1) P`` (depths unchanged), so that every reprojection residual is the
    pixel residual divided by the person's size in that view.

    ``xy: (P, M, J, 2)``, ``P: (P, M, 3, 4)``, ``size: (P, M)`` px (> 0) -> the same shapes.

    >>> xy, P = np.full((1, 1, 17, 2), 100.0), np.hstack([np.eye(3), np.ones((3, 1))])[None, None]
    >>> xy_s, P_s = in_person_sizes(xy, P, np.array([[50.0]]))
    >>> xy_s[0, 0, 0], P_s[0, 0]
    (array([2., 2.]), array([[0.02, 0.  , 0.  , 0.02],
           [0.  , 0.02, 0.  , 0.02],
           [0.  , 0.  , 1.  , 1.  ]]))
    """
    inverse = 1.0 / size
    scale = np.stack([inverse, inverse, np.ones_like(inverse)], axis=-1)          # (P, M, 3)
    return xy * inverse[..., None, None], P * scale[..., None]
