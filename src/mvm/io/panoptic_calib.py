"""CMU Panoptic Studio calibration (``calibration_<sequence>.json``) as a rig calibration.

``cameras[]`` hold ``name``, ``type`` (``hd``, ``vga``, ``kinect-color``), ``resolution``, ``K``,
``distCoef`` (OpenCV ``k1, k2, p1, p2, k3``), ``R`` and ``t`` (world -> camera, centimetres).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..scene import Cameras
from .calib_toml import RigCalibration


def read_panoptic_calibration(path: str | Path, types: tuple[str, ...] = ("hd",)) -> RigCalibration:
    """Read the cameras of the given ``types`` (world units: centimetres, as in the file)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(path, None, f"cannot read JSON: {e}") from None
    if not isinstance(data, dict) or not isinstance(data.get("cameras"), list):
        raise InputError(path, "cameras", "missing, or not a list")
    K, R, t, size, names, dist = [], [], [], [], [], []
    for i, cam in enumerate(data["cameras"]):
        if cam.get("type") not in types:
            continue
        try:
            K.append(np.asarray(cam["K"], dtype=float).reshape(3, 3))
            R.append(np.asarray(cam["R"], dtype=float).reshape(3, 3))
            t.append(np.asarray(cam["t"], dtype=float).reshape(3))
            size.append(np.asarray(cam["resolution"], dtype=float).reshape(2))
            dist.append(np.asarray(cam.get("distCoef", []), dtype=float).reshape(-1))
            names.append(str(cam["name"]))
        except KeyError as e:
            raise InputError(path, f"cameras[{i}].{e.args[0]}", "missing") from None
        except (TypeError, ValueError) as e:
            raise InputError(path, f"cameras[{i}]", f"bad value: {e}") from None
    if not names:
        raise InputError(path, "cameras", f"no camera of type {', '.join(types)}")
    cameras = Cameras(np.array(K), np.array(R), np.array(t), np.array(size), tuple(names))
    return RigCalibration(cameras, tuple(dist), np.zeros(len(names), dtype=bool),
                          {"source": str(path), "units": "cm"})
