"""Reading the ground truth of a simulated rig, ``RIG_DIR.groundtruth.json`` beside the rig
folder (format ``mvm.rig.groundtruth/1``, written by :mod:`mvm.io.rig_simulation`)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.checks import load_json_object, matrix
from mvm.io.rig_simulation import TRUTH_FORMAT


@dataclass
class RigTruth:
    """A simulated rig's truth.

    Attributes:
        cameras: ``V`` names; centers: ``(V, 3)`` true camera centres (metres).
        offsets: camera -> its frame offset (camera ``c``'s frame ``f`` shows instant ``f + offsets[c]``).
        instants: ``(S,)`` the scene's instants; poses3d: ``(S, G, 17, 3)`` true joints (metres).
    """

    cameras: list[str]
    centers: np.ndarray
    offsets: dict
    instants: np.ndarray
    poses3d: np.ndarray


def read_rig_truth(path: str | Path) -> RigTruth:
    """Read and check ``RIG_DIR.groundtruth.json``; any problem is one :class:`InputError` line."""
    path = Path(path)
    data = load_json_object(path, what="a rig ground truth object")
    if data.get("format") != TRUTH_FORMAT:
        raise InputError(path, "format", f"expected {TRUTH_FORMAT!r}, got {data.get('format')!r}")
    cameras = data.get("cameras")
    extrinsics, offsets = data.get("extrinsics"), data.get("offsets")
    if not isinstance(cameras, list) or not all(isinstance(c, str) for c in cameras):
        raise InputError(path, "cameras", "expected a list of camera names")
    if not isinstance(extrinsics, dict) or not isinstance(offsets, dict) or set(cameras) - set(extrinsics) \
            or set(cameras) - set(offsets):
        raise InputError(path, "extrinsics", "expected the centre and the offset of every camera")
    centers = np.array([matrix(extrinsics[c].get("center") if isinstance(extrinsics[c], dict) else None, (3,),
                               path, f"extrinsics.{c}.center") for c in cameras]).reshape(len(cameras), 3)
    if not all(isinstance(offsets[c], int) and not isinstance(offsets[c], bool) for c in cameras):
        raise InputError(path, "offsets", "expected a whole number of frames per camera")
    try:
        instants = np.array(data.get("instants"), dtype=np.int64).reshape(-1)
        poses3d = np.array(data.get("poses3d"), dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise InputError(path, "poses3d", "expected instants and (S, G, 17, 3) joints") from None
    if poses3d.ndim != 4 or poses3d.shape[0] != len(instants) or poses3d.shape[2:] != (17, 3) \
            or not np.isfinite(poses3d).all():
        raise InputError(path, "poses3d", f"expected ({len(instants)}, G, 17, 3) finite joints, got {poses3d.shape}")
    return RigTruth(list(cameras), centers, {c: int(offsets[c]) for c in cameras}, instants, poses3d)
