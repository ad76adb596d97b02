"""Marker trajectories in the ``.trc`` text layout of OpenSim, as Pose2Sim writes them::

    PathFileType	4	(X/Y/Z)	person_0.trc
    DataRate	CameraRate	NumFrames	NumMarkers	Units	OrigDataRate	OrigDataStartFrame	OrigNumFrames
    30.0	30.0	100	17	m	30.0	1	100
    Frame#	Time	nose			left_eye			…
    		X1	Y1	Z1	X2	Y2	Z2	…
    <blank line>
    1	0.000000	x	y	z	…

Tab separated, one row per frame; a missing marker is written as empty fields (read back as NaN).
Coordinates are written as given: convert them (units, up axis) with :func:`to_opensim` first.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.checks import read_text
from mvm.io.files import atomic_write_text

#: Rotations taking a world whose up axis is the key to OpenSim's Y-up frame (right-handed).
#: "+z" is Pose2Sim's conversion (X, Y, Z) -> (Y, Z, X); "-y" suits OpenCV/COLMAP/Panoptic worlds.
UP_ROTATIONS = {
    "+y": np.eye(3),
    "+z": np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]]),
    "-y": np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]]),
    "-z": np.array([[0.0, 1, 0], [0, 0, -1], [-1, 0, 0]]),
}


@dataclass
class Trc:
    """The content of a ``.trc`` file: ``points: (T, L, 3)`` (NaN: missing), ``markers``: L names,
    ``frames: (T,)`` frame numbers, ``times: (T,)`` seconds, ``rate`` Hz, ``units``, ``comment``
    (what follows the file name on the first line)."""

    points: np.ndarray
    markers: tuple[str, ...]
    frames: np.ndarray
    times: np.ndarray
    rate: float
    units: str
    comment: str = ""


def to_opensim(points: np.ndarray, up: str = "+z", metres_per_unit: float = 1.0) -> np.ndarray:
    """World points to OpenSim's frame: Y up, metres. ``points: (..., 3)`` -> ``(..., 3)``.

    ``up``: the world's up axis, one of ``+y``, ``+z``, ``-y``, ``-z``.
    """
    if up not in UP_ROTATIONS:
        raise ValueError(f"up: expected one of {sorted(UP_ROTATIONS)}, got {up!r}")
    return metres_per_unit * np.asarray(points, dtype=float) @ UP_ROTATIONS[up].T


def trc_text(points: np.ndarray, markers, rate: float, frames: np.ndarray | None = None,
             name: str = "markers.trc", units: str = "m", decimals: int = 6, comment: str = "") -> str:
    """The ``.trc`` text of ``points: (T, L, 3)`` for ``L`` marker names at ``rate`` Hz.

    ``comment`` (one line, e.g. how gaps were filled) follows the file name on the first line,
    after a tab: readers of the layout (OpenSim, Pose2Sim) take only the first fields of that line."""
    points = np.asarray(points, dtype=float)
    markers = list(markers)
    if points.ndim != 3 or points.shape[2] != 3 or points.shape[1] != len(markers):
        raise ValueError(f"trc: expected points (T, {len(markers)}, 3), got {points.shape}")
    if not rate > 0:
        raise ValueError(f"trc: rate must be > 0, got {rate}")
    T, L, _ = points.shape
    frames = np.arange(1, T + 1) if frames is None else np.asarray(frames, dtype=int)
    first = int(frames[0]) if T else 1
    comment = " ".join(str(comment).split())
    header = [
        f"PathFileType\t4\t(X/Y/Z)\t{name}" + (f"\t{comment}" if comment else ""),
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{rate:g}\t{rate:g}\t{T}\t{L}\t{units}\t{rate:g}\t{first}\t{T}",
        "Frame#\tTime\t" + "\t\t\t".join(markers) + "\t\t",
        "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(L)),
        "",
    ]
    number = f"%.{decimals}f"
    row_format = "\t".join([number] * (3 * L))                            # a row with every marker, at once
    values = points.reshape(T, 3 * L).tolist()
    complete = np.isfinite(points).reshape(T, 3 * L).all(1).tolist()
    times = ((frames - first) / rate).tolist()
    rows = [f"{f}\t{t:.6f}\t" + (row_format % tuple(r) if ok else
                                   "\t".join("" if v != v or v in (math.inf, -math.inf) else number % v for v in r))
            for f, t, r, ok in zip(frames.tolist(), times, values, complete)]
    return "\n".join(header + rows) + "\n"


def write_trc(path: str | Path, points: np.ndarray, markers, rate: float,
              frames: np.ndarray | None = None, units: str = "m", comment: str = "") -> None:
    """Write ``points: (T, L, 3)`` as a ``.trc`` file, atomically (``comment``: see :func:`trc_text`)."""
    path = Path(path)
    atomic_write_text(path, trc_text(points, markers, rate, frames, path.name, units, comment=comment))


def read_trc(path: str | Path) -> Trc:
    """Read a ``.trc`` file (OpenSim / Pose2Sim layout); problems raise :class:`InputError`."""
    path = Path(path)
    lines = read_text(path).splitlines()
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise InputError(path, "line 1", "expected a 'PathFileType' header")
    keys = lines[1].split("\t")
    values = lines[2].split("\t")
    meta = dict(zip([k.strip() for k in keys], [v.strip() for v in values]))
    try:
        rate = float(meta["DataRate"])
        n_markers = int(meta["NumMarkers"])
        units = meta.get("Units", "m")
    except (KeyError, ValueError):
        raise InputError(path, "line 3", "expected DataRate, NumMarkers and Units values") from None
    if not (math.isfinite(rate) and rate > 0):
        raise InputError(path, "line 3", f"DataRate must be a number > 0, got {meta['DataRate']!r}")
    if n_markers < 0:
        raise InputError(path, "line 3", f"NumMarkers must be >= 0, got {n_markers}")
    markers = tuple(m.strip() for m in lines[3].split("\t")[2:] if m.strip())
    if len(markers) != n_markers:
        raise InputError(path, "line 4", f"NumMarkers is {n_markers} but {len(markers)} marker names follow")
    frames, times, rows = [], [], []
    width = 2 + 3 * n_markers
    for number, line in enumerate(lines[5:], start=6):
        if not line.strip():
            continue
        fields = line.rstrip("\n").split("\t")
        if len(fields) > width and any(f.strip() for f in fields[width:]):
            raise InputError(path, f"line {number}", f"expected at most {width} columns "
                                                     f"(frame, time, {n_markers} × X, Y, Z), got {len(fields)}")
        fields += [""] * (width - len(fields))
        try:
            frame = float(fields[0])
            time = float(fields[1])
            row = [float(v) if v.strip() else np.nan for v in fields[2:width]]
        except ValueError as e:
            raise InputError(path, f"line {number}", f"not a number: {e}") from None
        if not (math.isfinite(frame) and frame == int(frame) and abs(frame) < 2 ** 53) or not math.isfinite(time):
            raise InputError(path, f"line {number}", "frame number and time must be finite, "
                                                     "the frame number an integer below 2^53")
        if np.isinf(row).any():
            raise InputError(path, f"line {number}", "infinite coordinate")
        frames.append(int(frame))
        times.append(time)
        rows.append(row)
    points = np.array(rows, dtype=float).reshape(len(rows), n_markers, 3)
    comment = "\t".join(lines[0].split("\t")[4:]).strip()
    return Trc(points, markers, np.array(frames, dtype=np.int64), np.array(times), rate, units, comment)
