"""Qualisys Track Manager calibrations (``.qca.txt``, QTM's calibration export, XML)::

    <calibration ...>
      <cameras>
        <camera serial="cam01" model="Miqus Video" viewrotation="0" avg-residual="0.40" ...>
          <fov_video left="0" top="0" right="1087" bottom="1919"/>
          <transform x="1460.2" y="-1909.2" z="1896.5" r11=".." r12=".." ... r33=".."/>
          <intrinsic focalLengthU="107599.7" focalLengthV="107588.8" centerPointU="34110.3"
                     centerPointV="60680.8" skew="0" radialDistortion1="-0.046" radialDistortion2="0.14"
                     radialDistortion3="0" tangentalDistortion1="0.0006" tangentalDistortion2="0.0007" .../>

What each value means and how it is converted (``b``: the binning factor, ``--binning``):

- ``focalLength*``, ``centerPoint*``, ``skew``: the sensor's subpixel units, 1/64 pixel. In the
  video's pixels: ``fx = focalLengthU / 64 / b``, ``cx = (centerPointU / 64 - left) / b``, with
  ``left`` and ``top`` of ``fov_video``, the sensor window the video records.
- image size: ``fov_video``'s ``right - left + 1`` by ``bottom - top + 1``, divided by ``b``
  (a video binned 2 x 2, Miqus 540p on a 1080p sensor, has ``b = 2``).
- lens: ``[k1, k2, p1, p2, k3]`` = radial 1, 2, tangential 1, 2, radial 3, taken as the
  dimensionless OpenCV coefficients they are (they do not change with the pixel size).
  Pose2Sim divides them by 64 as well; on the sample rig's checkerboard photos the values as
  written fit better (docs/rigs.md).
- ``transform``: the camera's position ``(x, y, z)`` in millimetres and a rotation matrix ``M``
  (``M[i, j] = r{i+1}{j+1}``) from the world to QTM's camera axes, which look along -z with y
  up; OpenCV's look along +z with y down, a half turn about x: ``R = diag(1, -1, -1) M`` and
  ``t = -R C`` with ``C`` the position in metres.
- only video cameras are converted: a camera whose ``model`` names neither video nor hybrid
  (a marker camera) is left out; ``model="none"`` or no model counts as video.
- ``viewrotation`` other than 0 (a camera mounted on its side, its video turned in QTM) is
  refused: the intrinsics are the sensor's, the video's pixels are not.
"""
from __future__ import annotations

import numpy as np

from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration
from mvm.io.calibrations.common import ForeignCamera, assemble, camera_center_pose, floats, parse_xml

#: Subpixels per pixel of QTM's sensor units.
SUBPIXELS = 64
#: QTM's camera axes (y up, looking along -z) -> OpenCV's (y down, along +z): a half turn about x.
QTM_TO_OPENCV = np.diag([1.0, -1.0, -1.0])
_ROTATION_KEYS = tuple(f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3))


def _attributes(element, keys, path, field) -> np.ndarray:
    if element is None:
        raise InputError(path, field, "missing")
    return np.array([floats(element.get(k), 1, path, f"{field}.{k}")[0] for k in keys])


def is_video_camera(model: str | None) -> bool:
    """Whether a QTM camera ``model`` records video (Miqus Video, hybrid, or not said)."""
    model = (model or "none").lower()
    return any(word in model for word in ("video", "hybrid", "none"))


def read_qualisys(path, binning: float = 1.0) -> RigCalibration:
    """The video cameras of the QTM calibration ``path`` (module docstring), in file order;
    ``binning``: the binning factor of the videos (1: full resolution). Returns a
    :class:`RigCalibration` in metres."""
    if not binning > 0:
        raise InputError(None, "--binning", f"expected a number > 0, got {binning}")
    root = parse_xml(path, "a Qualisys calibration (.qca.txt)")
    elements = root.findall("cameras/camera")
    if root.tag != "calibration" or not elements:
        raise InputError(path, None, "not a Qualisys calibration: expected <calibration><cameras><camera ...>")
    cameras = []
    for i, element in enumerate(elements):
        field = f"camera[{i}]"
        name = element.get("serial")
        if not name:
            raise InputError(path, f"{field}.serial", "missing")
        if not is_video_camera(element.get("model")):
            continue
        if element.get("viewrotation", "0").strip() not in ("0", ""):
            raise InputError(path, f"{field}.viewrotation",
                             f"camera {name}: {element.get('viewrotation')}: a video turned from the sensor is not "
                             "converted (record it unturned, or turn the calibration)")
        left, top, right, bottom = _attributes(element.find("fov_video"), ("left", "top", "right", "bottom"), path,
                                               f"{field}.fov_video")
        intrinsic = element.find("intrinsic")
        fu, fv, cu, cv = _attributes(intrinsic, ("focalLengthU", "focalLengthV", "centerPointU", "centerPointV"), path,
                                     f"{field}.intrinsic") / SUBPIXELS
        skew = float(floats(intrinsic.get("skew", "0"), 1, path, f"{field}.intrinsic.skew")[0]) / SUBPIXELS
        k1, k2, k3, p1, p2 = _attributes(intrinsic, ("radialDistortion1", "radialDistortion2", "radialDistortion3",
                                                     "tangentalDistortion1", "tangentalDistortion2"),
                                         path, f"{field}.intrinsic")
        transform = element.find("transform")
        position = _attributes(transform, ("x", "y", "z"), path, f"{field}.transform")
        M = _attributes(transform, _ROTATION_KEYS, path, f"{field}.transform").reshape(3, 3)
        R, t = camera_center_pose(QTM_TO_OPENCV @ M, position / 1000.0)
        K = np.array([[fu, skew, cu - left], [0.0, fv, cv - top], [0.0, 0.0, 1.0]])
        K[:2] /= binning
        size = np.array([right - left + 1, bottom - top + 1]) / binning
        cameras.append(ForeignCamera(name, K, np.array([k1, k2, p1, p2, k3]), R, t, size, field))
    if not cameras:
        raise InputError(path, None, f"no video camera among its {len(elements)} cameras (model names none)")
    return assemble(cameras, path, {"method": "converted from Qualisys (.qca.txt)", "units": "m",
                                    "source": str(path), "binning": float(binning)})
