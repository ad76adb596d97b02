"""Persons a rig instant's cameras do not support: a person that explains fewer than
``rig_min_support`` of the cameras it projects into, or whose body has no human proportions, is
a cluster of false poses that agree in a few cameras, not someone the cameras around the people
saw. Arrays in, arrays out."""
from __future__ import annotations

import numpy as np

from mvm.core.association import credible
from mvm.core.config import Config
from mvm.core.scene import Cameras
from mvm.core.triangulate import Triangulation


def drop_unsupported(cameras: Cameras, groups: list[np.ndarray], tri: Triangulation, config: Config) -> None:
    """Leave unreconstructed in ``tri``, in place, the persons of rig instants that the 3D
    association would refuse (:func:`mvm.core.association.credible` with ``rig_min_support``):
    those explaining too few of the cameras they project into, and clusters of false poses that
    triangulate to no body. With the paper's grouping, which has no such step."""
    if not len(tri.X):
        return
    usable = np.isfinite(tri.X).all(-1).sum(-1) >= config.min_person_joints
    keep = credible(groups, tri.X, tri.inliers.sum(1), cameras.P, cameras.size, usable, config.min_group_size,
                    config.rig_min_support, config.association_max_proportion_deviation, config.max_bone_ratio,
                    agreed=True)
    tri.X[~keep] = np.nan
    tri.inliers[~keep] = False                         # no point, no inliers, as RANSAC leaves them
