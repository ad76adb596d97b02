"""Camera trajectories in the RealEstate10K / MannequinChallenge text format.

Line 1 is the source video's URL. Every further line is one frame::

    timestamp_us fx fy cx cy 0 0 r11 r12 r13 t1 r21 r22 r23 t2 r31 r32 r33 t3

intrinsics normalised by the image width (fx, cx) and height (fy, cy), and the 3×4
world -> camera matrix row-major (translation in arbitrary SfM units).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.checks import read_text

#: Numbers on a frame line: timestamp, 4 intrinsics, 2 distortion zeros, 12 pose entries.
FIELDS_PER_LINE = 19


@dataclass(frozen=True)
class Trajectory:
    """``F`` frames of a real camera path.

    Attributes:
        url: the source video.
        timestamps_us: ``(F,)`` microseconds, increasing.
        intrinsics: ``(F, 4)`` fx, fy, cx, cy normalised by the image width / height.
        R: ``(F, 3, 3)`` world -> camera rotations; t: ``(F, 3)`` translations (SfM units).
    """

    url: str
    timestamps_us: np.ndarray
    intrinsics: np.ndarray
    R: np.ndarray
    t: np.ndarray

    def __len__(self) -> int:
        return len(self.timestamps_us)

    @property
    def centers(self) -> np.ndarray:
        """Camera centres ``C = -R^T t``: ``(F, 3)``."""
        return -np.einsum("fji,fj->fi", self.R, self.t)


def parse_trajectory(text: str, source: str | Path = "<trajectory>") -> Trajectory:
    """Parse the text of a trajectory file; errors name ``source`` and the line."""
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise InputError(source, "line 1", "expected the source video's URL, got an empty line")
    url = lines[0].strip()
    rows = []
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        parts = line.split()
        if len(parts) != FIELDS_PER_LINE:
            raise InputError(source, f"line {number}", f"expected {FIELDS_PER_LINE} numbers, got {len(parts)}")
        try:
            values = np.array([float(p) for p in parts])
        except ValueError:
            raise InputError(source, f"line {number}", f"not a number in {line.strip()[:60]!r}") from None
        if not np.isfinite(values).all():
            raise InputError(source, f"line {number}", "non-finite number")
        R = values[7:].reshape(3, 4)[:, :3]
        if np.abs(R).max() > 1.01 or abs(np.linalg.det(R) - 1.0) > 1e-2 or np.abs(R @ R.T - np.eye(3)).max() > 1e-2:
            raise InputError(source, f"line {number}", "the 3×3 part of the pose is not a rotation")
        if (values[1:3] <= 0).any():
            raise InputError(source, f"line {number}", "focal lengths must be > 0")
        rows.append(values)
    if len(rows) < 2:
        raise InputError(source, None, f"expected at least 2 frame lines, got {len(rows)}")
    data = np.array(rows)
    if (np.diff(data[:, 0]) <= 0).any():
        bad = int(np.flatnonzero(np.diff(data[:, 0]) <= 0)[0]) + 3
        raise InputError(source, f"line {bad}", "timestamps must increase")
    Rt = data[:, 7:].reshape(-1, 3, 4)
    return Trajectory(url, data[:, 0], data[:, 1:5], Rt[:, :, :3], Rt[:, :, 3])


def read_trajectory(path: str | Path) -> Trajectory:
    """Read a RealEstate10K / MannequinChallenge camera file."""
    path = Path(path)
    return parse_trajectory(read_text(path), path)
