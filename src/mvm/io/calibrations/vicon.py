"""Vicon calibrations (``.xcp``, Vicon Nexus / Tracker, XML)::

    <Cameras VERSION="1.0">
      <Camera DEVICEID="2114875" SYSTEM="DV" SENSOR_SIZE="1920 1080" PIXEL_ASPECT_RATIO="1" ...>
        <KeyFrames>
          <KeyFrame FOCAL_LENGTH="1496.4" PRINCIPAL_POINT="961.2 541.7"
                    ORIENTATION="qx qy qz qw" POSITION="x y z" WORLD_ERROR="0.31"
                    VICON_RADIAL2="ThreeParameter cx cy k1 k2 k3"/>

How each value is converted:

- only the video cameras (``SYSTEM="DV"``: Vicon Vue and the cameras of a video system) are
  converted, each named by its ``DEVICEID``;
- ``FOCAL_LENGTH``: pixels, ``fx``; ``fy = fx / PIXEL_ASPECT_RATIO``; ``PRINCIPAL_POINT``:
  ``cx cy`` in pixels; the image size is ``SENSOR_SIZE`` (the video records the whole sensor);
- ``ORIENTATION``: a quaternion ``(x, y, z, w)``, scalar last, whose rotation matrix is the
  world -> camera rotation in OpenCV's camera axes; ``POSITION``: the camera centre in
  millimetres, so ``t = -R C`` with ``C`` in metres;
- lens: ``VICON_RADIAL2``'s ``k1 k2 k3`` (its first three numbers are the model name and the
  distortion centre, which the OpenCV model takes to be the principal point), else
  ``VICON_RADIAL``'s ``k1 k2``; written as ``[k1, k2, 0, 0, k3]``.
"""
from __future__ import annotations

import numpy as np

from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration
from mvm.io.calibrations.common import (
    ForeignCamera,
    assemble,
    camera_center_pose,
    floats,
    parse_xml,
    quaternion_matrix,
)


def _lens(keyframe, path, field) -> np.ndarray:
    """``[k1, k2, 0, 0, k3]`` of a key frame's ``VICON_RADIAL2`` (model name, centre x, y,
    k1, k2, k3) or ``VICON_RADIAL`` (k1, k2)."""
    radial2 = keyframe.get("VICON_RADIAL2")
    if radial2 is not None:
        parts = radial2.split()
        k = floats(" ".join(parts[3:]), None, path, f"{field}.VICON_RADIAL2")
        if len(parts) < 5 or len(k) not in (2, 3):
            raise InputError(path, f"{field}.VICON_RADIAL2", f"expected a model name, the centre x y and 2 or 3 "
                                                             f"coefficients, got {radial2[:60]!r}")
        k1, k2, k3 = np.append(k, 0.0)[:3]
        return np.array([k1, k2, 0.0, 0.0, k3])
    radial = keyframe.get("VICON_RADIAL")
    if radial is None:
        return np.zeros(5)
    k1, k2 = floats(radial, 2, path, f"{field}.VICON_RADIAL")
    return np.array([k1, k2, 0.0, 0.0, 0.0])


def read_vicon(path, binning: float = 1.0) -> RigCalibration:
    """The video cameras (``SYSTEM="DV"``) of the Vicon calibration ``path`` (module
    docstring), in file order, in metres. ``binning`` is not used (Vicon writes the video's
    pixels)."""
    root = parse_xml(path, "a Vicon calibration (.xcp)")
    elements = root.findall("Camera")
    if root.tag != "Cameras" or not elements:
        raise InputError(path, None, "not a Vicon calibration: expected <Cameras><Camera ...>")
    cameras = []
    for i, element in enumerate(elements):
        if element.get("SYSTEM") != "DV":
            continue
        field = f"Camera[{i}]"
        name = element.get("DEVICEID") or element.get("USERID")
        if not name:
            raise InputError(path, f"{field}.DEVICEID", "missing")
        keyframe = element.find("KeyFrames/KeyFrame")
        if keyframe is None:
            raise InputError(path, f"{field}.KeyFrames", f"camera {name}: no KeyFrame (not calibrated)")
        field = f"{field}.KeyFrame"
        f = floats(keyframe.get("FOCAL_LENGTH"), 1, path, f"{field}.FOCAL_LENGTH")[0]
        aspect = floats(element.get("PIXEL_ASPECT_RATIO", "1"), 1, path, f"Camera[{i}].PIXEL_ASPECT_RATIO")[0]
        if aspect <= 0:
            raise InputError(path, f"Camera[{i}].PIXEL_ASPECT_RATIO", f"must be > 0, got {aspect:g}")
        cx, cy = floats(keyframe.get("PRINCIPAL_POINT"), 2, path, f"{field}.PRINCIPAL_POINT")
        size = floats(element.get("SENSOR_SIZE"), 2, path, f"Camera[{i}].SENSOR_SIZE")
        q = floats(keyframe.get("ORIENTATION"), 4, path, f"{field}.ORIENTATION")
        if not np.linalg.norm(q) > 0:
            raise InputError(path, f"{field}.ORIENTATION", "a zero quaternion")
        position = floats(keyframe.get("POSITION"), 3, path, f"{field}.POSITION")
        R, t = camera_center_pose(quaternion_matrix(q), position / 1000.0)
        K = np.array([[f, 0.0, cx], [0.0, f / aspect, cy], [0.0, 0.0, 1.0]])
        cameras.append(ForeignCamera(name, K, _lens(keyframe, path, field), R, t, size, f"Camera[{i}]"))
    if not cameras:
        raise InputError(path, None, f"no video camera (SYSTEM=\"DV\") among its {len(elements)} cameras")
    return assemble(cameras, path, {"method": "converted from Vicon (.xcp)", "units": "m", "source": str(path)})
