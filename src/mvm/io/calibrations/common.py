"""What every converter of a foreign calibration shares: one camera as read, checked and
assembled into the project's :class:`~mvm.io.calib_toml.RigCalibration`, the rotations the
foreign files write (quaternions, Rodrigues vectors) and a guarded XML parse.

Conventions of the result (those of Calib.toml, :mod:`mvm.io.calib_toml`): ``x_cam = R @ X + t``
with ``R`` world -> camera and OpenCV's camera axes (x right, y down, z forward along the
optical axis), pixel coordinates with the origin at the centre of the top-left pixel, and the
world in metres.
"""
from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass

import cv2
import numpy as np

from mvm.core.scene import Cameras
from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration
from mvm.io.checks import read_bytes
from mvm.io.paths import name_problem

#: Distortion lengths OpenCV's pinhole model takes (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1..s4 [tx ty]]]]).
OPENCV_LENGTHS = (4, 5, 8, 12, 14)
#: How far from a rotation a rotation matrix read from a file may be (max |R R^T - I|).
ROTATION_TOLERANCE = 1e-3


@dataclass(frozen=True)
class ForeignCamera:
    """One camera as a converter read it, already in mvm's conventions.

    Attributes:
        name: the camera's name (becomes its Calib.toml table).
        K: ``(3, 3)`` intrinsics in pixels.
        distortion: ``(n,)`` OpenCV coefficients, n in :data:`OPENCV_LENGTHS` (or 0).
        R: ``(3, 3)`` rotation, world -> camera (OpenCV camera axes).
        t: ``(3,)`` translation, world -> camera, metres.
        size: ``(2,)`` image width and height in pixels.
        field: where in the source it came from, for refusals (``camera[2]``, ``cam_01``).
    """

    name: str
    K: np.ndarray
    distortion: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: np.ndarray
    field: str


def floats(text: str | None, count: int | None, path, field: str) -> np.ndarray:
    """The whitespace-separated numbers of ``text`` (an XML attribute) as a finite ``(count,)``
    array (any length when ``count`` is None); anything else raises one :class:`InputError`."""
    if text is None:
        raise InputError(path, field, "missing")
    try:
        values = np.array([float(v) for v in text.split()], dtype=float)
    except ValueError:
        raise InputError(path, field, f"expected numbers, got {text[:40]!r}") from None
    if count is not None and len(values) != count:
        raise InputError(path, field, f"expected {count} numbers, got {len(values)}")
    if not np.isfinite(values).all():
        raise InputError(path, field, "not a finite number")
    return values


def parse_xml(path, what: str) -> ElementTree.Element:
    """The root element of the XML file ``path`` (read the guarded way); a document that
    declares entities or a DTD (the way XML bombs expand) and one that does not parse raise
    one :class:`InputError` saying it is not ``what``."""
    data = read_bytes(path)
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        raise InputError(path, None, f"refusing an XML document type declaration (not {what})")
    try:
        return ElementTree.fromstring(data)
    except ElementTree.ParseError as e:
        raise InputError(path, None, f"not {what}: XML error {e}") from None


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """The rotation matrix of the quaternion ``q = (x, y, z, w)`` (scalar last), ``(3, 3)``:
    ``R v`` turns ``v`` as the quaternion product ``q v q*`` does. ``q`` need not be of unit length.

    >>> np.round(quaternion_matrix(np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])), 6) + 0
    array([[ 0., -1.,  0.],
           [ 1.,  0.,  0.],
           [ 0.,  0.,  1.]])
    """
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def rotation(value: np.ndarray, path, field: str) -> np.ndarray:
    """A world -> camera rotation written as a Rodrigues vector ``(3,)`` (or ``(3, 1)``) or a
    matrix ``(3, 3)``, as a checked ``(3, 3)`` matrix."""
    value = np.asarray(value, dtype=float)
    if value.size == 3:
        return cv2.Rodrigues(value.reshape(3))[0]
    if value.shape != (3, 3):
        raise InputError(path, field, f"expected a Rodrigues vector (3) or a 3x3 matrix, got shape {value.shape}")
    return value


def camera_center_pose(R_world_camera: np.ndarray, center_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World -> camera ``(R, t)`` of a camera at ``center_m`` ``(3,)`` with rotation
    ``R_world_camera`` ``(3, 3)``: ``t = -R C`` (so that ``R C + t = 0``)."""
    return R_world_camera, -R_world_camera @ center_m


def _check(camera: ForeignCamera, path) -> None:
    K, R, where = camera.K, camera.R, camera.field
    for label, value in (("intrinsics", K), ("rotation", R), ("translation", camera.t), ("size", camera.size),
                         ("distortion", camera.distortion)):
        if not np.isfinite(value).all():
            raise InputError(path, where, f"camera {camera.name}: its {label} is not finite")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(path, where, f"camera {camera.name}: focal lengths must be > 0, got {K[0, 0]:g}, {K[1, 1]:g}")
    if not np.allclose(K[2], [0.0, 0.0, 1.0]) or K[1, 0] != 0:
        raise InputError(path, where, f"camera {camera.name}: intrinsics not of the form [[fx, s, cx], [0, fy, cy], "
                                      "[0, 0, 1]]")
    if np.abs(R @ R.T - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(R) < 0:
        raise InputError(path, where, f"camera {camera.name}: not a rotation (not orthonormal, or a reflection)")
    if (camera.size <= 0).any():
        raise InputError(path, where, f"camera {camera.name}: image size must be > 0, got "
                                      f"{camera.size[0]:g} x {camera.size[1]:g}")
    if len(camera.distortion) not in (0, *OPENCV_LENGTHS):
        raise InputError(path, where, f"camera {camera.name}: {len(camera.distortion)} distortion coefficients, "
                                      f"OpenCV takes {', '.join(map(str, OPENCV_LENGTHS))}")
    problem = name_problem(camera.name)
    if problem:
        raise InputError(path, where, f"camera name {camera.name!r}: {problem}")


def assemble(cameras: list[ForeignCamera], path, metadata: dict) -> RigCalibration:
    """The :class:`RigCalibration` of ``cameras`` (in their order), each checked: finite,
    positive focal lengths, a proper rotation (re-orthonormalized by SVD), a valid name, names
    unique. ``metadata`` becomes the Calib.toml's ``[metadata]`` table."""
    if not cameras:
        raise InputError(path, None, "no camera found")
    names = [c.name for c in cameras]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise InputError(path, None, f"duplicate camera names: {', '.join(duplicates)}")
    for camera in cameras:
        _check(camera, path)
    R = np.array([c.R for c in cameras])
    u, _, vt = np.linalg.svd(R)
    R = u @ vt                                      # the nearest rotation to each (round-off of the file)
    K = np.array([c.K for c in cameras])
    t = np.array([c.t for c in cameras])
    size = np.array([c.size for c in cameras])
    return RigCalibration(Cameras(K, R, t, size, tuple(names), tuple(np.asarray(c.distortion, float) for c in cameras)),
                          {"adjusted": False, "error": 0.0, **metadata})

