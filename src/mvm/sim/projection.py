"""What a camera sees of simulated people: exact projections, the frame, the people's image
sizes and depth-ordered occlusion between bodies."""
from __future__ import annotations

import numpy as np

from mvm.core.camera import project_views
from mvm.core.keypoints import NUM_JOINTS
from mvm.core.scene import Cameras

#: Limbs used as occluders (joint pairs), with the torso as two diagonals.
OCCLUDER_LIMBS = np.array([(5, 7), (7, 9), (6, 8), (8, 10), (11, 13), (13, 15), (12, 14), (14, 16),
                           (5, 12), (6, 11), (5, 6), (11, 12), (0, 5), (0, 6)])
#: Joints nearer than this to the camera's plane are not seen. [m]
MIN_DEPTH_M = 0.1


def project_people(cameras: Cameras, poses3d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact projections of ``poses3d: (G, 17, 3)`` in every view: ``uv: (V, G, 17, 2)`` px
    and camera depths ``(V, G, 17)``."""
    return project_views(cameras, poses3d)


def in_frame(uv: np.ndarray, depth: np.ndarray, width: float, height: float) -> np.ndarray:
    """Joints inside the ``width`` x ``height`` image and in front of the camera.
    ``uv: (..., 2)`` px, ``depth: (...)`` metres -> ``(...)`` bool."""
    return ((uv[..., 0] >= 0) & (uv[..., 0] < width) & (uv[..., 1] >= 0) & (uv[..., 1] < height)
            & (depth > MIN_DEPTH_M))


def image_size_of_people(uv: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Larger side of the box of the in-frame joints. ``uv: (..., G, 17, 2)``,
    ``inside: (..., G, 17)`` -> ``(..., G)`` px (0 for a person with no joint in the frame)."""
    hi = np.where(inside[..., None], uv, -np.inf).max(axis=-2)
    lo = np.where(inside[..., None], uv, np.inf).min(axis=-2)
    return np.where(inside.any(axis=-1), (hi - lo).max(axis=-1), 0.0)


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of ``points: (..., 2)`` to segments ``a, b: (..., 2)`` (broadcast)."""
    ab = b - a
    t = np.clip(((points - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0, 1)
    return np.linalg.norm(points - (a + t[..., None] * ab), axis=-1)


def occluded_joints(uv: np.ndarray, depth: np.ndarray, focal: float, limb_radius: float = 0.07) -> np.ndarray:
    """Which joints are hidden behind another person in one view.

    ``uv: (G, 17, 2)`` pixels, ``depth: (G, 17)`` camera z -> ``(G, 17)`` bool: a joint is
    hidden when it lies within ``limb_radius`` (metres, at the occluder's depth) of a limb of a
    person whose limb is nearer the camera than the joint by more than 0.15 m. Only the pairs
    of people whose boxes overlap and whose depths allow it are tested, all at once.
    """
    G = len(uv)
    limbs_a = uv[:, OCCLUDER_LIMBS[:, 0]]                                # (G, L, 2)
    limbs_b = uv[:, OCCLUDER_LIMBS[:, 1]]
    limb_depth = 0.5 * (depth[:, OCCLUDER_LIMBS[:, 0]] + depth[:, OCCLUDER_LIMBS[:, 1]])
    radius = focal * limb_radius / np.maximum(limb_depth, 1e-3)          # (G, L) px
    # Candidate (person, occluder) pairs: overlapping boxes, the occluder partly nearer.
    reach = radius.max(axis=1)[:, None]
    lo, hi = uv.min(axis=1), uv.max(axis=1)                              # (G, 2)
    limb_lo = np.minimum(limbs_a, limbs_b).min(axis=1) - reach
    limb_hi = np.maximum(limbs_a, limbs_b).max(axis=1) + reach
    overlap = ((lo[:, None] <= limb_hi[None]) & (limb_lo[None] <= hi[:, None])).all(-1)    # (G, G)
    overlap &= limb_depth.min(axis=1)[None] < depth.max(axis=1)[:, None] - 0.15
    np.fill_diagonal(overlap, False)
    person, occluder = np.nonzero(overlap)
    hidden = np.zeros((G, NUM_JOINTS), bool)
    if len(person):
        dist = _segment_distance(uv[person][:, :, None, :], limbs_a[occluder][:, None], limbs_b[occluder][:, None])
        nearer = limb_depth[occluder][:, None] < depth[person][:, :, None] - 0.15             # (P, J, L)
        covered = ((dist < radius[occluder][:, None]) & nearer).any(axis=2)                   # (P, J)
        np.logical_or.at(hidden, person, covered)
    return hidden
