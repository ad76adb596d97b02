"""A calibration made by another system, converted for a rig folder (``mvm rig calibrate
--convert``): read it (:mod:`mvm.io.calibrations`), keep the rig's cameras, write a Calib.toml
atomically.

The rig's cameras are those of ``RIG_DIR/videos/`` and of its pose sources (``pose/``). Each
must match one camera of the converted calibration by name, the way pose folders are matched
(:func:`~mvm.rig.rigdir.match_cameras`: exact, then without case and suffixes, then by camera
number); a rig camera without one is refused, naming it, and nothing is written. Cameras of the
calibration that the rig does not have are left out (listed in the result). A rig folder with
neither videos nor poses gets every camera of the calibration.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration, write_calib_toml
from mvm.io.calibrations import detect_format, read_foreign_calibration, source_files
from mvm.io.layout import POSE_DIR, VIDEOS
from mvm.io.outputs import check_output_location
from mvm.io.paths import videos_by_name
from mvm.rig.rigdir import match_cameras, pose_sources, subset_calibration

log = logging.getLogger(__name__)


@dataclass
class RigConversion:
    """A converted calibration: ``calibration`` (written at ``path``), its ``format``, the
    cameras of the source ``left_out`` (not in the rig) and whether the rig's cameras were
    ``matched`` (False: the rig had none, every camera was kept)."""

    calibration: RigCalibration
    format: str
    left_out: tuple[str, ...]
    matched: bool
    path: Path


def rig_camera_sources(rig_dir: Path) -> dict[str, dict[str, Path]]:
    """The rig's cameras by where they come from: ``{"videos": {name: video}, "pose":
    {name: source}}`` (empty groups left out)."""
    groups = {VIDEOS: videos_by_name(rig_dir / VIDEOS), POSE_DIR: pose_sources(rig_dir)}
    return {k: v for k, v in groups.items() if v}


def keep_rig_cameras(calibration: RigCalibration, groups: dict[str, dict[str, Path]], source) -> np.ndarray:
    """Indices (increasing) of the cameras of ``calibration`` that the rig's cameras ``groups``
    (:func:`rig_camera_sources`) match; a rig camera that matches none raises :class:`InputError`
    naming it and ``source``."""
    names = calibration.cameras.names
    kept: set[int] = set()
    for group, entries in groups.items():
        try:
            matched = match_cameras(names, list(entries))
        except ValueError as e:
            raise InputError(source, None, str(e)) from None
        missing = [e for i, e in enumerate(entries) if i not in matched.values()]
        if missing:
            raise InputError(source, None, f"no camera for {', '.join(missing)} of the rig's {group}/ (cameras in the "
                                           f"calibration: {', '.join(names)})")
        kept.update(matched)
    return np.array(sorted(kept), dtype=int)


def convert_rig_calibration(rig_dir: str | Path, source: str | Path, out: str | Path, fmt: str | None = None,
                            binning: float = 1.0) -> RigConversion:
    """Convert the calibration ``source`` (``fmt``: a name of :data:`mvm.io.calibrations.FORMATS`,
    None: told from the file) for the cameras of ``rig_dir`` (module docstring) and write it as
    Calib.toml at ``out``; ``binning``: Qualisys's binning factor. ``out`` being one of the files
    read (the calibration's, the rig's videos and pose files) or lying inside one is refused before
    any work."""
    rig_dir, source = Path(rig_dir), Path(source)
    if not rig_dir.is_dir():
        raise InputError(rig_dir, None, "not a folder (the rig folder whose cameras the calibration is for)")
    fmt = fmt or detect_format(source)
    groups = rig_camera_sources(rig_dir)
    inputs = [source, *source_files(source, fmt)] + [p for entries in groups.values() for p in entries.values()]
    check_output_location(out, inputs, replaced=False)
    calibration = read_foreign_calibration(source, fmt, binning)
    left_out: tuple[str, ...] = ()
    if groups:
        index = keep_rig_cameras(calibration, groups, source)
        left_out = tuple(n for i, n in enumerate(calibration.cameras.names) if i not in set(index))
        if left_out:
            log.info("%s: cameras not in the rig, left out: %s", source, ", ".join(left_out))
        calibration = subset_calibration(calibration, index)
    calibration = replace(calibration, metadata={**calibration.metadata, "format": fmt,
                                                 "cameras": list(calibration.cameras.names),
                                                 "left_out": list(left_out)})
    out = Path(out)
    write_calib_toml(out, calibration)
    return RigConversion(calibration, fmt, left_out, bool(groups), out)
