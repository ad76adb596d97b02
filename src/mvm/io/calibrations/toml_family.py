"""The TOML calibrations of anipose / aniposelib, FreeMoCap and caliscope.

anipose, aniposelib (``CameraGroup.dump``) and FreeMoCap write the layout of Calib.toml
(:mod:`mvm.io.calib_toml`): ``[cam_0]`` with ``name``, ``size``, ``matrix``, ``distortions``,
``rotation`` (Rodrigues, world -> camera), ``translation``. Their translations are in the units
of the calibration board's square size as the user gave it: FreeMoCap millimetres, anipose
whatever its config said. The units are told from the rig's size: cameras whose centres lie a
median of more than :data:`MM_SPACING` apart are taken to be in millimetres (no rig spans 20 m
between its cameras; none in millimetres spans less than 20 mm), else in metres; the metadata
records which.

caliscope (``config.toml``, or ``camera_array.toml`` in recent versions): ``[cam_N]`` with
``port``, ``size``, ``matrix``, ``distortions``, ``rotation`` (a 3 x 3 matrix, or a Rodrigues
vector), ``translation`` in metres, ``rotation_count`` (quarter turns caliscope gave the
frames), ``ignore``. Each camera is named ``cam_<port>``; ignored cameras and cameras without
extrinsics are left out (the latter with a refusal when none is left). A camera with
``rotation_count`` other than 0 was calibrated on frames turned that many quarter turns: its
videos must be turned the same way (the metadata lists them; a warning says so).
"""
from __future__ import annotations

import logging

import numpy as np

from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration, parse_calib
from mvm.io.calibrations.common import ForeignCamera, assemble, rotation
from mvm.io.checks import integer, load_toml, matrix, numbers

log = logging.getLogger(__name__)

#: Median distance between camera centres above which a TOML calibration is in millimetres.
MM_SPACING = 20.0


def is_caliscope(data: dict) -> bool:
    """Whether a parsed TOML document is caliscope's (a ``cam_*`` table with ``port``)."""
    return any(isinstance(v, dict) and "port" in v for k, v in data.items() if k.startswith("cam"))


def median_spacing(centers: np.ndarray) -> float:
    """Median distance between the camera centres ``(V, 3)`` (0 for one camera)."""
    d = np.linalg.norm(centers[:, None] - centers[None], axis=-1)[np.triu_indices(len(centers), 1)]
    return float(np.median(d)) if d.size else 0.0


def read_anipose(path, binning: float = 1.0, system: str = "anipose") -> RigCalibration:
    """The cameras of an anipose / aniposelib / FreeMoCap ``calibration.toml`` (module
    docstring), in metres. ``binning`` is not used."""
    data = load_toml(path)
    if is_caliscope(data):
        raise InputError(path, None, "a caliscope calibration (its cameras have a port): use --format caliscope")
    calibration = parse_calib(data, path)
    cams = calibration.cameras
    spacing = median_spacing(cams.centers)
    scale = 1e-3 if spacing > MM_SPACING else 1.0
    cameras = [ForeignCamera(n, cams.K[v], calibration.distortions[v], cams.R[v], cams.t[v] * scale, cams.size[v],
                             f"[{n}]") for v, n in enumerate(cams.names)]
    if calibration.fisheye.any():
        raise InputError(path, None, "fisheye cameras are not converted (copy the file: it is a Calib.toml)")
    units = (f"mm (cameras a median {spacing:.0f} apart, more than {MM_SPACING:g}), converted to m" if scale != 1
             else f"m (cameras a median {spacing:.3g} apart)")
    return assemble(cameras, path, {"method": f"converted from {system} (calibration.toml)", "units": "m",
                                    "source": str(path), "source_units": units})


def read_freemocap(path, binning: float = 1.0) -> RigCalibration:
    """FreeMoCap's calibration TOML: anipose's layout (:func:`read_anipose`)."""
    return read_anipose(path, binning, "FreeMoCap")


def read_caliscope(path, binning: float = 1.0) -> RigCalibration:
    """The calibrated, not ignored cameras of a caliscope ``config.toml`` (module docstring),
    in port order, in metres. ``binning`` is not used."""
    data = load_toml(path)
    if not is_caliscope(data):
        raise InputError(path, None, "not a caliscope calibration: expected [cam_N] tables with port, matrix, "
                                     "rotation, translation")
    cameras, turned, uncalibrated = [], [], []
    tables = sorted(((k, v) for k, v in data.items() if k.startswith("cam") and isinstance(v, dict) and "port" in v),
                    key=lambda item: integer(item[1]["port"], path, f"[{item[0]}].port"))
    for key, table in tables:
        if table.get("ignore") is True:
            continue
        name = f"cam_{integer(table['port'], path, f'[{key}].port')}"
        if table.get("translation") is None or table.get("rotation") is None or table.get("matrix") is None:
            uncalibrated.append(name)
            continue
        for required in ("size", "distortions"):
            if required not in table:
                raise InputError(path, f"[{key}].{required}", "missing")
        K = matrix(table["matrix"], (3, 3), path, f"[{key}].matrix")
        rot = table["rotation"]
        nested = isinstance(rot, list) and bool(rot) and isinstance(rot[0], list)
        R = rotation(matrix(rot, (3, 3), path, f"[{key}].rotation") if nested
                     else numbers(rot, path, f"[{key}].rotation", (3,)), path, f"[{key}].rotation")
        t = numbers(table["translation"], path, f"[{key}].translation", (3,))
        size = numbers(table["size"], path, f"[{key}].size", (2,))
        dist = numbers(table["distortions"], path, f"[{key}].distortions")
        if integer(table.get("rotation_count", 0), path, f"[{key}].rotation_count") % 4:
            turned.append(name)
        cameras.append(ForeignCamera(name, K, dist, R, t, size, f"[{key}]"))
    if not cameras and uncalibrated:
        raise InputError(path, None, f"no camera has extrinsics (rotation, translation): {', '.join(uncalibrated)}")
    if turned:
        log.warning("%s: %s calibrated on frames turned by rotation_count: turn their videos the same way",
                    path, ", ".join(turned))
    return assemble(cameras, path, {"method": "converted from caliscope (config.toml)", "units": "m",
                                    "source": str(path), "turned_cameras": turned,
                                    "uncalibrated_cameras": uncalibrated})
