"""Preparing a rig folder from its 2D poses: ``sync.toml`` (:mod:`mvm.rig.synchronize`) and a
calibration from the people (:mod:`mvm.rig.calibrate`). The I/O around the math: read the rig,
check it, run, write atomically; every problem is one :class:`~mvm.errors.InputError` naming
the camera or the file, and nothing is written then."""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration, write_calib_toml
from mvm.io.layout import RigLayout
from mvm.io.outputs import check_output_location
from mvm.io.sync_toml import write_sync_toml
from mvm.rig.calibrate import CalibrationError, PeopleCalibration, calibrate_from_people
from mvm.rig.output_set import rig_inputs
from mvm.rig.rigdir import RigData, find_calibration, read_rig
from mvm.rig.synchronize import MIN_OVERLAP_FRAMES, SyncError, SyncResult, fundamental_matrix, synchronize

log = logging.getLogger(__name__)

#: Largest offset searched by default. [frames]
DEFAULT_MAX_OFFSET = 60


@dataclass
class RigSync:
    """The offsets found for a rig folder: ``names`` of the cameras (the first is the
    reference), ``result`` (:class:`~mvm.rig.synchronize.SyncResult`), ``calibrated`` (the
    calibration's extrinsics were used), ``path`` of the ``sync.toml`` written (None: not written)."""

    names: tuple[str, ...]
    result: SyncResult
    calibrated: bool
    path: Path | None


def _two_cameras(rig: RigData, source) -> None:
    if len(rig.calibration.cameras) < 2:
        raise InputError(source, None, f"one camera with 2D poses ({rig.calibration.cameras.names[0]}): "
                                       "a rig needs at least two")


def synchronize_rig(rig_dir: str | Path, calib: str | Path | None = None, max_offset: int | None = None,
                    write: bool = True) -> RigSync:
    """Find every camera's offset in ``rig_dir`` and write ``rig_dir/sync.toml``.

    The calibration (``calib`` or the rig's) may lack extrinsics: the epipolar geometry is
    then estimated from the people. ``max_offset`` (frames) defaults to ``DEFAULT_MAX_OFFSET``
    or what the shortest video allows."""
    rig_dir = Path(rig_dir)
    source = Path(calib) if calib else find_calibration(rig_dir)
    rig = read_rig(rig_dir, source, extrinsics=False, sync=False)
    _two_cameras(rig, source)
    cams = rig.calibration.cameras
    det = rig.detections
    frame = rig.frames[det.instant]
    lengths = np.array([np.ptp(frame[det.view == c]) + 1 if (det.view == c).any() else 0 for c in range(len(cams))])
    shortest = int(np.argmin(lengths))
    room = int(lengths[shortest]) - MIN_OVERLAP_FRAMES
    if room < 0:
        raise InputError(rig.sources[cams.names[shortest]], None,
                         f"camera {cams.names[shortest]}: {lengths[shortest]} frames, fewer than the "
                         f"{MIN_OVERLAP_FRAMES} needed to synchronize")
    if max_offset is None:
        max_offset = min(DEFAULT_MAX_OFFSET, room)
    elif max_offset > room:
        raise InputError("--max-offset", str(max_offset),
                         f"beyond the videos' length: camera {cams.names[shortest]} has {lengths[shortest]} frames, "
                         f"so offsets of at most {room} can be found")
    calibrated = bool(np.isfinite(cams.R).all() and np.isfinite(cams.t).all())
    fundamentals = None
    if calibrated:
        fundamentals = [None] + [fundamental_matrix(cams.K[0], cams.R[0], cams.t[0], cams.K[c], cams.R[c], cams.t[c])
                                 for c in range(1, len(cams))]
    try:
        result = synchronize(det.keypoints, det.view, frame, cams.K, max_offset, fundamentals)
    except SyncError as e:
        name = cams.names[e.camera]
        raise InputError(rig.sources[name], None, f"camera {name}: {e.problem}") from None
    path = None
    if write:
        path = RigLayout(rig_dir).sync
        ambiguous = [n for n, a in zip(cams.names, result.ambiguous) if a]
        write_sync_toml(path, {n: int(o) for n, o in zip(cams.names, result.offsets)},
                        {"reference": cams.names[0], "calibration": str(source),
                         "method": "triangulation error of each alignment"
                                   + (" (calibration)" if calibrated else " (epipolar geometry from the people)"),
                         "max_offset": int(max_offset), "ambiguous": ambiguous,
                         "correlation_peak": [round(float(p), 4) for p in result.peak],
                         "error_px": [round(float(e), 3) if np.isfinite(e) else -1.0 for e in result.error_px]})
    return RigSync(cams.names, result, calibrated, path)


@dataclass
class RigPeopleCalibration:
    """A calibration from the people: ``calibration`` (written at ``path``), the math's
    ``result`` (:class:`~mvm.rig.calibrate.PeopleCalibration`), the ``sync`` offsets used
    (None: frame numbers as they are)."""

    calibration: RigCalibration
    result: PeopleCalibration
    sync: dict | None
    path: Path


def calibrate_rig_from_people(rig_dir: str | Path, out: str | Path, intrinsics: str | Path | None = None,
                              seed: int = 0, refine_focal: bool = False) -> RigPeopleCalibration:
    """Every camera's rotation and position from the 2D poses of ``rig_dir`` (synchronized by
    its ``sync.toml`` when there is one), with the intrinsics of ``intrinsics`` or of the rig's
    calibration (rotations and translations, if any, are ignored; ``refine_focal``: the focal
    lengths are adjusted too); a full Calib.toml is written at ``out`` with each camera's
    residual in ``[metadata]`` and its position's standard deviation (``position_sd_m``, metres,
    relative to the first camera) in its own table; only the intrinsics of the calibration are
    used, never its rotations and translations; ``out`` being or lying inside an input of the rig is refused
    before any work (:func:`mvm.io.outputs.check_output_location`)."""
    rig_dir = Path(rig_dir)
    source = Path(intrinsics) if intrinsics else find_calibration(rig_dir)
    check_output_location(out, rig_inputs(rig_dir, source), replaced=False)
    rig = read_rig(rig_dir, source, extrinsics=False)
    _two_cameras(rig, source)
    cams = rig.calibration.cameras
    det = rig.detections
    try:
        found = calibrate_from_people(det.keypoints, det.view, det.instant, cams, seed, refine_focal)
    except CalibrationError as e:
        where = rig.sources[cams.names[e.camera]] if e.camera is not None else rig_dir
        name = f"camera {cams.names[e.camera]}: " if e.camera is not None else ""
        raise InputError(where, None, name + e.problem) from None
    metadata = {"adjusted": True, "error": round(float(np.mean(found.residual_px)), 4),
                "method": "from people (mvm rig calibrate --from-people)", "units": "m",
                "intrinsics": str(source), "cameras": list(cams.names),
                "residual_px": [round(float(r), 4) for r in found.residual_px]}
    if refine_focal:
        metadata["focal_refined"] = [round(float(k), 5) for k in found.focal_scale]
    notes = tuple({"position_sd_m": round(float(sd), 4)} for sd in found.position_sd_m)
    calibration = RigCalibration(found.cameras, metadata, notes)
    out = Path(out)
    write_calib_toml(out, calibration)
    return RigPeopleCalibration(calibration, found, rig.offsets, out)
