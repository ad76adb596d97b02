"""bioCV calibrations: one text file per camera (``00.calib``, ``01.calib``, ... or without a
type), numbers separated by spaces, one row a line (empty lines are skipped)::

    1920                    image width, pixels
    1080                    image height
    fx 0 cx                 intrinsics, 3 rows
    0 fy cy
    0 0 1
    r11 r12 r13 tx          world -> camera [R | t], 3 rows, t in millimetres
    r21 r22 r23 ty
    r31 r32 r33 tz
    k1 k2 p1 p2 [k3]        OpenCV distortion

Given one file, its set is read: the files of its folder with the same type (``.calib``, or
none); given a folder, its ``*.calib`` files. Each camera is named by its file name without
the type, in natural order.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mvm.core.names import natural_key
from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration
from mvm.io.calibrations import BIOCV_SUFFIX
from mvm.io.calibrations.common import ForeignCamera, assemble
from mvm.io.checks import read_text


def biocv_files(path) -> dict[str, Path]:
    """``{camera: file}`` of the set ``path`` belongs to (module docstring)."""
    path = Path(path)
    if path.is_dir():
        files = list(path.glob(f"*{BIOCV_SUFFIX}"))
    else:
        files = [p for p in path.parent.iterdir() if p.is_file() and p.suffix == path.suffix
                 and not p.name.startswith(".")]
    if not files:
        raise InputError(path, None, f"no bioCV calibration file (*{BIOCV_SUFFIX}) found")
    return {p.stem: p for p in sorted(files, key=lambda p: natural_key(p.name))}


def _rows(path: Path, root: Path | None = None) -> list[np.ndarray]:
    rows = []
    for number, line in enumerate(read_text(path, root).splitlines(), 1):
        if not line.strip():
            continue
        try:
            row = np.array([float(v) for v in line.split()])
        except ValueError:
            raise InputError(path, f"line {number}", f"expected numbers, got {line.strip()[:40]!r}") from None
        if not np.isfinite(row).all():
            raise InputError(path, f"line {number}", "not a finite number")
        rows.append(row)
    return rows


def read_biocv_camera(path: Path, name: str, root: Path | None = None) -> ForeignCamera:
    """One bioCV camera file (module docstring), inside ``root`` when given (a link leading out
    of the set's folder is refused)."""
    rows = _rows(path, root)
    expected = "width, height, 3 rows of K, 3 rows of [R | t], the distortion"
    if len(rows) != 9:
        raise InputError(path, None, f"not a bioCV calibration: {len(rows)} lines of numbers, expected 9 ({expected})")
    shapes = [len(r) for r in rows]
    if shapes[:8] != [1, 1, 3, 3, 3, 4, 4, 4] or shapes[8] not in (4, 5, 8):
        raise InputError(path, None, f"not a bioCV calibration: lines of {shapes} numbers, expected "
                                     "[1, 1, 3, 3, 3, 4, 4, 4] and 4, 5 or 8 coefficients")
    RT = np.array(rows[5:8])
    return ForeignCamera(name, np.array(rows[2:5]), rows[8], RT[:, :3], RT[:, 3] / 1000.0,
                         np.array([rows[0][0], rows[1][0]]), path.name)


def read_biocv(path, binning: float = 1.0) -> RigCalibration:
    """The cameras of a set of bioCV calibration files (module docstring), in metres.
    ``binning`` is not used."""
    cameras = []
    folder = Path(path) if Path(path).is_dir() else Path(path).parent
    for name, file in biocv_files(path).items():
        cameras.append(read_biocv_camera(file, name, folder))
    return assemble(cameras, path, {"method": "converted from bioCV (per-camera calibration files)", "units": "m",
                                    "source": str(path)})
