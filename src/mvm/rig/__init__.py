"""Synchronized camera rigs: every instant is a static scene whose views are the cameras.

- :mod:`mvm.rig.rigdir`: reading a rig directory (calibration + 2D poses per camera);
- :mod:`mvm.rig.instants`: the rig driver of the core pipeline (:mod:`mvm.core.pipeline`), instants in batches;
- :mod:`mvm.rig.tracking`: identities over time and optional smoothing;
- :mod:`mvm.rig.recap`: reprojection error per keypoint, camera exclusions;
- :mod:`mvm.rig.reconstruct_rig`: ``RIG_DIR`` in, JSON Lines + ``.trc`` + recap out.
"""
from mvm.rig.options import RigOptions

__all__ = ["RigOptions"]
