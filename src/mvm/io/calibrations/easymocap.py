"""EasyMocap calibrations: ``intri.yml`` and ``extri.yml`` side by side (OpenCV FileStorage YAML)::

    intri.yml                                  extri.yml
    names: ["01", "02"]                        names: ["01", "02"]
    K_01: !!opencv-matrix (3 x 3, pixels)      R_01: !!opencv-matrix (3 x 1, Rodrigues, world -> camera)
    dist_01: !!opencv-matrix (1 x 5)           Rot_01: !!opencv-matrix (3 x 3, the same rotation)
    H_01: 1080   W_01: 1920   (optional)       T_01: !!opencv-matrix (3 x 1, metres)

Either file may be given (or their folder): the other is read from beside it. The rotation is
``Rot_`` when present, else ``R_``; the image size ``W_`` x ``H_`` when present, else twice the
principal point (as Pose2Sim does; a warning says so). EasyMocap works in metres and in OpenCV's
conventions, so nothing else changes.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration
from mvm.io.calibrations import EASYMOCAP_FILES
from mvm.io.calibrations.common import ForeignCamera, assemble, rotation
from mvm.io.checks import read_text

log = logging.getLogger(__name__)

INTRINSICS, EXTRINSICS = EASYMOCAP_FILES


def easymocap_files(path) -> tuple[Path, Path]:
    """``(intri.yml, extri.yml)`` of ``path``: either file, or a folder holding both."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    files = folder / INTRINSICS, folder / EXTRINSICS
    for f in files:
        if not f.is_file():
            raise InputError(f, None, f"file not found: EasyMocap's {INTRINSICS} and {EXTRINSICS} go side by side")
    return files


class _Storage:
    """One FileStorage YAML file, its nodes read with checks."""

    def __init__(self, path: Path):
        import cv2

        self.path = path
        text = read_text(path)                           # the guarded read: a regular file of bounded size
        if not text.lstrip().startswith("%YAML"):
            raise InputError(path, None, "not an OpenCV FileStorage YAML file (no %YAML header)")
        try:
            self.fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        except cv2.error as e:
            problem = str(e).strip().splitlines()[-1][:120]
            raise InputError(path, None, f"not a valid OpenCV FileStorage file: {problem}") from None

    def names(self) -> list[str]:
        node = self.fs.getNode("names")
        if node.empty() or not node.isSeq():
            raise InputError(self.path, "names", "missing: expected the list of camera names")
        names = []
        for i in range(node.size()):
            item = node.at(i)
            names.append(item.string() if item.isString() else f"{item.real():g}")
        return names

    def matrix(self, key: str, sizes: tuple[int, ...], required: bool = True) -> np.ndarray | None:
        node = self.fs.getNode(key)
        if node.empty():
            if required:
                raise InputError(self.path, key, "missing")
            return None
        value = node.mat()
        if value is None or value.size not in sizes:
            raise InputError(self.path, key, f"expected a matrix of {' or '.join(map(str, sizes))} numbers")
        return value.astype(float)

    def number(self, key: str) -> float | None:
        node = self.fs.getNode(key)
        return None if node.empty() or not node.isReal() and not node.isInt() else float(node.real())


def read_easymocap(path, binning: float = 1.0) -> RigCalibration:
    """The cameras of EasyMocap's ``intri.yml`` and ``extri.yml`` (module docstring), in the
    order of the intrinsics' ``names``, in metres. ``binning`` is not used."""
    intri_path, extri_path = easymocap_files(path)
    intri, extri = _Storage(intri_path), _Storage(extri_path)
    names, extrinsic_names = intri.names(), set(extri.names())
    cameras, guessed = [], []
    for name in names:
        if name not in extrinsic_names:
            raise InputError(extri_path, "names", f"camera {name} of {INTRINSICS} is missing")
        K = intri.matrix(f"K_{name}", (9,)).reshape(3, 3)
        dist = intri.matrix(f"dist_{name}", (4, 5, 8, 12, 14), required=False)
        rot = extri.matrix(f"Rot_{name}", (9,), required=False)
        R = rotation(rot if rot is not None else extri.matrix(f"R_{name}", (3,)), extri_path, f"R_{name}")
        t = extri.matrix(f"T_{name}", (3,)).reshape(3)
        w, h = intri.number(f"W_{name}"), intri.number(f"H_{name}")
        if w is None or h is None:
            w, h = 2 * K[0, 2], 2 * K[1, 2]
            guessed.append(name)
        cameras.append(ForeignCamera(name, K, np.zeros(0) if dist is None else dist.reshape(-1), R, t,
                                     np.array([w, h]), f"K_{name}"))
    if guessed:
        log.warning("%s: no image size (W_, H_) for %s: taken as twice the principal point", intri_path,
                    ", ".join(guessed))
    return assemble(cameras, intri_path, {"method": "converted from EasyMocap (intri.yml, extri.yml)", "units": "m",
                                          "source": str(intri_path.parent), "size_guessed": guessed})
