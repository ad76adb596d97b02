"""Persons a rig instant's cameras do not support: a person that explains fewer than
``rig_min_support`` of the cameras it projects into is a cluster of false poses that agree in a
few cameras, not someone the cameras around the people saw. Arrays in, arrays out."""
from __future__ import annotations

import numpy as np

from mvm.core.association import visible_frames
from mvm.core.config import Config
from mvm.core.scene import Cameras
from mvm.core.triangulate import Triangulation


def drop_unsupported(cameras: Cameras, groups: list[np.ndarray], tri: Triangulation, config: Config) -> None:
    """Leave unreconstructed in ``tri``, in place, the persons of rig instants that explain
    fewer than ``rig_min_support`` of the cameras they project into (false poses that agree in
    a few cameras): with the paper's grouping, what the 3D association refuses."""
    if not len(tri.X):
        return
    count = np.array([len(g) for g in groups])
    with np.errstate(all="ignore"):
        visible = visible_frames(tri.X, cameras.P, cameras.size)
    tri.X[count < config.rig_min_support * visible] = np.nan
