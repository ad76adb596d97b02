"""OpenCap calibrations: one pickle per camera (``<session>/Videos/Cam0/cameraIntrinsicsExtrinsics.pickle``),
a dict of numpy arrays::

    intrinsicMat  (3, 3)  pixels
    distortion    (1, 5)  OpenCV k1 k2 p1 p2 k3
    imageSize     (2, 1)  height, width
    rotation      (3, 3)  world -> camera
    translation   (3, 1)  world -> camera, millimetres

Read only through :func:`mvm.io.safe_pickle.load_pickle` (numpy arrays and plain containers:
a pickle that would run code is refused). Given one pickle, its set is read: the same file name
in every sibling folder (OpenCap's ``Cam0/``, ``Cam1/``, each camera named by its folder), or
every ``*.pickle`` of its folder (each named by its file name); given a folder, the pickles in
it and in its sub-folders.

OpenCap's world is its calibration board's, the board standing upright: x along the board, y
down it, z into it. It is turned to have z up, as Pose2Sim does: ``X' = A X`` with
``A = Rz(pi) Rx(-pi/2)``, i.e. ``(x, y, z) -> (-x, -z, -y)``; so ``R' = R A^T`` and ``t`` is
unchanged (in metres).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mvm.core.names import natural_key
from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration
from mvm.io.calibrations.common import ForeignCamera, assemble
from mvm.io.safe_pickle import load_pickle

#: The file name OpenCap gives each camera's calibration.
OPENCAP_FILE = "cameraIntrinsicsExtrinsics.pickle"
#: OpenCap's board world -> a world with z up: ``X' = A X``.
BOARD_TO_Z_UP = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])


def opencap_folder(path) -> Path:
    """The folder of the set ``path`` belongs to: ``path`` itself, the parent of a camera's
    folder (``Cam1/cameraIntrinsicsExtrinsics.pickle``), or a flat file's folder. The set's files
    lie inside it (a link leading out is refused when read)."""
    path = Path(path)
    if path.is_dir():
        return path
    return path.parent.parent if path.name == OPENCAP_FILE else path.parent


def opencap_files(path) -> dict[str, Path]:
    """``{camera: pickle}`` of the set ``path`` belongs to (module docstring), in natural order:
    the ``<camera>/cameraIntrinsicsExtrinsics.pickle`` of its folder where there are any, else its
    ``<camera>.pickle`` files (one level only: another session's pickles further down are not
    this set's); a camera's folder given alone is that camera, named after its folder."""
    path, folder = Path(path), opencap_folder(path)
    files = {p.parent.name: p for p in folder.glob(f"*/{OPENCAP_FILE}")} or \
        {p.parent.name if p.name == OPENCAP_FILE else p.stem: p for p in folder.glob("*.pickle")}
    if not files:
        raise InputError(path, None, "no OpenCap calibration pickle (*.pickle) found")
    return dict(sorted(files.items(), key=lambda item: natural_key(item[0])))


def _array(data: dict, key: str, sizes: tuple[int, ...], path) -> np.ndarray:
    if key not in data:
        raise InputError(path, key, "missing")
    try:
        value = np.asarray(data[key], dtype=float)
    except (TypeError, ValueError):
        raise InputError(path, key, "expected numbers") from None
    if value.size not in sizes:
        raise InputError(path, key, f"expected {' or '.join(map(str, sizes))} numbers, got {value.size}")
    return value.reshape(-1)


def read_opencap(path, binning: float = 1.0) -> RigCalibration:
    """The cameras of OpenCap's calibration pickles (module docstring), in metres, the world
    turned to have z up. ``binning`` is not used."""
    cameras = []
    for name, file in opencap_files(path).items():
        data = load_pickle(file, root=opencap_folder(path))
        if not isinstance(data, dict):
            raise InputError(file, None, f"not an OpenCap calibration: expected a dict, got {type(data).__name__}")
        K = _array(data, "intrinsicMat", (9,), file).reshape(3, 3)
        dist = _array(data, "distortion", (4, 5, 8, 12, 14), file)
        height, width = _array(data, "imageSize", (2,), file)
        R = _array(data, "rotation", (9,), file).reshape(3, 3)
        t = _array(data, "translation", (3,), file) / 1000.0
        cameras.append(ForeignCamera(name, K, dist, R @ BOARD_TO_Z_UP.T, t, np.array([width, height]), name))
    return assemble(cameras, path, {"method": "converted from OpenCap (calibration pickles)", "units": "m",
                                    "source": str(path), "world": "OpenCap's board turned to z up"})
