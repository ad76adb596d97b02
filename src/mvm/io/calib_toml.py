"""Rig calibrations in the ``Calib.toml`` layout shared by anipose, Pose2Sim and FreeMocap.

One table per camera and an optional ``[metadata]`` table::

    [cam_01]
    name = "cam_01"
    size = [ 1920.0, 1080.0,]
    matrix = [ [ 1500.0, 0.0, 960.0,], [ 0.0, 1500.0, 540.0,], [ 0.0, 0.0, 1.0,],]
    distortions = [ -0.1, 0.01, 0.0, 0.0,]
    rotation = [ 0.1, -0.2, 0.0,]          # Rodrigues vector, world -> camera (absent: intrinsics only)
    translation = [ 0.5, 1.0, 4.0,]       # world -> camera, world units (Pose2Sim: metres)
    fisheye = false

    [metadata]
    adjusted = false
    error = 0.0

``distortions`` are OpenCV coefficients: ``[k1, k2, p1, p2]`` (Pose2Sim), ``[k1, k2, p1, p2, k3]``
(anipose) or longer; with ``fisheye = true``, OpenCV fisheye ``[k1, k2, k3, k4]`` (the lens model of
:mod:`mvm.core.camera`, which applies and undoes them). Cameras are
returned in file order and addressed by ``name`` (the table's key when ``name`` is absent).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from mvm.core.scene import Cameras
from mvm.errors import InputError
from mvm.io.checks import load_toml, matrix, numbers
from mvm.io.files import atomic_write_text
from mvm.io.paths import check_name


@dataclass(frozen=True)
class RigCalibration:
    """The calibrated cameras of a rig: :class:`~mvm.core.scene.Cameras` (their lenses included)
    and what the file says besides.

    Attributes:
        cameras: ``V`` cameras (``K``, world -> camera ``R``, ``t``, image sizes, names, lenses).
        metadata: the ``[metadata]`` table (empty when absent).
        camera_notes: ``V`` tables of further keys written into each camera's table (what its
            calibration knows of it, e.g. ``position_sd_m``; other tools ignore them), or empty.
    """

    cameras: Cameras
    metadata: dict = field(default_factory=dict)
    camera_notes: tuple[dict, ...] = ()

    @property
    def distortions(self) -> tuple[np.ndarray, ...]:
        """``V`` arrays of OpenCV distortion coefficients (may be empty): the cameras' lenses."""
        return self.cameras.distortion

    @property
    def fisheye(self) -> np.ndarray:
        """``(V,)`` bool, OpenCV fisheye model."""
        return self.cameras.fisheye

    def index(self, name: str) -> int:
        return self.cameras.names.index(name)


def _array(table: dict, key: str, shape: tuple, path, section: str) -> np.ndarray:
    """``table[key]`` as a finite float array of ``shape`` (``()``: a flat list of any length)."""
    field = f"[{section}].{key}"
    if key not in table:
        raise InputError(path, field, "missing")
    if shape:
        return matrix(table[key], shape, path, field)
    return numbers(table[key], path, field)


def _check_camera(K: np.ndarray, R: np.ndarray, size: np.ndarray, path, section: str) -> None:
    """Focal lengths > 0, last row of ``K`` (0, 0, 1), a finite rotation, image size > 0."""
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(path, f"[{section}].matrix", f"focal lengths must be > 0, got {K[0, 0]:g}, {K[1, 1]:g}")
    if not np.allclose(K[2], [0.0, 0.0, 1.0]) or K[1, 0] != 0:
        raise InputError(path, f"[{section}].matrix", "expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    if not np.isfinite(R).all():
        raise InputError(path, f"[{section}].rotation", "not a valid Rodrigues vector")
    if (size <= 0).any():
        raise InputError(path, f"[{section}].size", f"width and height must be > 0, got {size[0]:g}, {size[1]:g}")


CAMERA_KEYS = frozenset(("matrix", "rotation", "translation", "size", "distortions"))
"""The keys that make a table of a Calib.toml a camera."""


def parse_calib(data: dict, path: str | Path = "<calib>", extrinsics: bool = True) -> RigCalibration:
    """Build a :class:`RigCalibration` from a parsed Calib.toml document (``path`` names it in errors).
    ``extrinsics=False`` accepts cameras without ``rotation`` and ``translation`` (intrinsics only):
    their ``R`` and ``t`` are NaN."""
    K, R, t, size, names, dist, fisheye = [], [], [], [], [], [], []
    metadata = {}
    for section, table in data.items():
        if section == "metadata":
            metadata = dict(table) if isinstance(table, dict) else {}
            continue
        if not isinstance(table, dict) or not CAMERA_KEYS & set(table):
            continue                                   # not a camera: another tool's table
        if "matrix" not in table:
            present = ", ".join(sorted(CAMERA_KEYS & set(table)))
            raise InputError(path, f"[{section}].matrix", f"missing: a camera table (it has {present}) "
                                                          "needs matrix, rotation, translation and size")
        name = table.get("name", section)
        if not isinstance(name, str) or not name:
            raise InputError(path, f"[{section}].name", f"expected a string, got {name!r}")
        check_name(name, path, f"[{section}].name")
        K.append(_array(table, "matrix", (3, 3), path, section))
        known = extrinsics or "rotation" in table or "translation" in table
        rvec = _array(table, "rotation", (3,), path, section) if known else None
        R.append(cv2.Rodrigues(rvec)[0] if known else np.full((3, 3), np.nan))
        t.append(_array(table, "translation", (3,), path, section) if known else np.full(3, np.nan))
        size.append(_array(table, "size", (2,), path, section))
        _check_camera(K[-1], R[-1] if known else np.eye(3), size[-1], path, section)
        d = _array(table, "distortions", (), path, section).reshape(-1) if "distortions" in table else np.zeros(0)
        fish = table.get("fisheye", False)
        if not isinstance(fish, bool):
            raise InputError(path, f"[{section}].fisheye", f"expected true or false, got {fish!r}")
        if fish and len(d) not in (0, 4):
            raise InputError(path, f"[{section}].distortions", f"fisheye expects 4 coefficients, got {len(d)}")
        if not fish and len(d) not in (0, 4, 5, 8, 12, 14):
            raise InputError(path, f"[{section}].distortions",
                             f"expected 4, 5, 8, 12 or 14 OpenCV coefficients, got {len(d)}")
        dist.append(d)
        fisheye.append(fish)
        names.append(name)
    if not names:
        raise InputError(path, None, "no camera table (a table with 'matrix', 'rotation', 'translation', 'size')")
    if len(set(names)) != len(names):
        raise InputError(path, "name", f"duplicate camera names: {sorted(n for n in set(names) if names.count(n) > 1)}")
    cameras = Cameras(np.array(K), np.array(R), np.array(t), np.array(size), tuple(names), tuple(dist),
                      np.array(fisheye, dtype=bool))
    return RigCalibration(cameras, metadata)


def read_calib_toml(path: str | Path, extrinsics: bool = True) -> RigCalibration:
    """Read a Calib.toml file; any problem raises one :class:`InputError` naming the table and key.
    ``extrinsics=False``: cameras may lack ``rotation`` and ``translation`` (:func:`parse_calib`)."""
    path = Path(path)
    return parse_calib(load_toml(path), path, extrinsics)


def _fmt(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        value = float(value)
        if not math.isfinite(value):
            raise ValueError(f"cannot write a non-finite number to TOML: {value}")
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[ " + " ".join(_fmt(v) + "," for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def calib_toml_text(calibration: RigCalibration) -> str:
    """The Calib.toml text of ``calibration`` (Pose2Sim's layout: one table per camera, then
    ``[metadata]``). A camera whose ``R`` or ``t`` is not finite (intrinsics only, as
    ``parse_calib(..., extrinsics=False)`` reads them) has no ``rotation`` nor ``translation``."""
    cams = calibration.cameras
    lines = []
    for v, name in enumerate(cams.names):
        posed = bool(np.isfinite(cams.R[v]).all() and np.isfinite(cams.t[v]).all())
        pose = [f"rotation = {_fmt(cv2.Rodrigues(cams.R[v])[0].reshape(3))}",
                f"translation = {_fmt(cams.t[v])}"] if posed else []
        lines += [f"[{_fmt(name) if not name.replace('_', '').replace('-', '').isalnum() else name}]",
                  f"name = {_fmt(name)}",
                  f"size = {_fmt(cams.size[v])}",
                  f"matrix = {_fmt([list(row) for row in cams.K[v]])}",
                  f"distortions = {_fmt(calibration.distortions[v])}",
                  *pose,
                  f"fisheye = {_fmt(bool(calibration.fisheye[v]))}"]
        notes = calibration.camera_notes[v] if calibration.camera_notes else {}
        lines += [f"{key} = {_fmt(value)}" for key, value in notes.items()] + [""]
    metadata = calibration.metadata or {"adjusted": False, "error": 0.0}
    lines.append("[metadata]")
    lines += [f"{key} = {_fmt(value)}" for key, value in metadata.items()]
    return "\n".join(lines) + "\n"


def write_calib_toml(path: str | Path, calibration: RigCalibration) -> None:
    """Write ``calibration`` as Calib.toml, atomically."""
    atomic_write_text(path, calib_toml_text(calibration))

