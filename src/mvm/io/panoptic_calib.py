"""CMU Panoptic Studio calibration (``calibration_<sequence>.json``) as a rig calibration.

``cameras[]`` hold ``name``, ``type`` (``hd``, ``vga``, ``kinect-color``), ``resolution``, ``K``,
``distCoef`` (OpenCV ``k1, k2, p1, p2, k3``), ``R`` and ``t`` (world -> camera, centimetres).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mvm.core.scene import Cameras
from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration
from mvm.io.checks import load_json, matrix, numbers
from mvm.io.paths import check_name


def _vector(value, n: int, path, field) -> np.ndarray:
    """``n`` numbers, flat (``[1, 2, 3]``) or as a column (``[[1], [2], [3]]``, Panoptic's ``t``)."""
    if isinstance(value, list) and len(value) == n and all(isinstance(v, list) for v in value):
        return matrix(value, (n, 1), path, field).reshape(n)
    return matrix(value, (n,), path, field)


def read_panoptic_calibration(path: str | Path, types: tuple[str, ...] = ("hd",)) -> RigCalibration:
    """Read the cameras of the given ``types`` (world units: centimetres, as in the file)."""
    path = Path(path)
    data = load_json(path)
    if not isinstance(data, dict) or not isinstance(data.get("cameras"), list):
        raise InputError(path, "cameras", "missing, or not a list")
    K, R, t, size, names, dist = [], [], [], [], [], []
    for i, cam in enumerate(data["cameras"]):
        field = f"cameras[{i}]"
        if not isinstance(cam, dict):
            raise InputError(path, field, "expected an object")
        if cam.get("type") not in types:
            continue
        for key in ("name", "K", "R", "t", "resolution"):
            if key not in cam:
                raise InputError(path, f"{field}.{key}", "missing")
        if not isinstance(cam["name"], (str, int)) or isinstance(cam["name"], bool):
            raise InputError(path, f"{field}.name", f"expected a string, got {type(cam['name']).__name__}")
        K.append(matrix(cam["K"], (3, 3), path, f"{field}.K"))
        R.append(matrix(cam["R"], (3, 3), path, f"{field}.R"))
        t.append(_vector(cam["t"], 3, path, f"{field}.t"))
        size.append(matrix(cam["resolution"], (2,), path, f"{field}.resolution"))
        dist.append(numbers(cam.get("distCoef", []), path, f"{field}.distCoef"))
        if K[-1][0, 0] <= 0 or K[-1][1, 1] <= 0:
            raise InputError(path, f"{field}.K", "focal lengths must be > 0")
        if (size[-1] <= 0).any():
            raise InputError(path, f"{field}.resolution", "width and height must be > 0")
        if (np.abs(R[-1]).max() > 1.01 or np.abs(R[-1] @ R[-1].T - np.eye(3)).max() > 1e-3
                or np.linalg.det(R[-1]) < 0):
            raise InputError(path, f"{field}.R", "not a rotation matrix")
        U, _, Vt = np.linalg.svd(R[-1])           # the nearest rotation: the file rounds entries
        R[-1] = U @ Vt
        names.append(check_name(str(cam["name"]), path, f"{field}.name"))
    if not names:
        raise InputError(path, "cameras", f"no camera of type {', '.join(types)}")
    if len(set(names)) != len(names):
        raise InputError(path, "cameras", "duplicate camera names")
    cameras = Cameras(np.array(K), np.array(R), np.array(t), np.array(size), tuple(names), tuple(dist))
    return RigCalibration(cameras, {"source": str(path), "units": "cm"})
