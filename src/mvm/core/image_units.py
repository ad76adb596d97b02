"""The unit of image distances in the reconstruction: the person's image size.

A detector's keypoint error grows with the person's size in the image (the camera's resolution,
its distance to the person, the detector), so the reconstruction measures every image distance
it thresholds or weighs in person sizes: pixels divided by ``s = sqrt(w h)``, the area of the
box of the person's keypoints in that view, as OKS and the association
(:mod:`mvm.core.association`) do. The same scene with its image coordinates and intrinsics
scaled by any factor then gives the same persons and the same 3D poses.

Arrays: ``P`` persons, ``M`` view slots, ``J`` joints.
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


def in_person_sizes(xy: np.ndarray, P: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints and projections whose image coordinates are in person sizes: ``xy / s`` and
    ``diag(1/s, 1/s, 1) P`` (depths unchanged), so that every reprojection residual is the
    pixel residual divided by the person's size in that view.

    ``xy: (P, M, J, 2)``, ``P: (P, M, 3, 4)``, ``size: (P, M)`` px (> 0) -> the same shapes.
    """
    inverse = 1.0 / size
    scale = np.stack([inverse, inverse, np.ones_like(inverse)], axis=-1)          # (P, M, 3)
    return xy * inverse[..., None, None], P * scale[..., None]
