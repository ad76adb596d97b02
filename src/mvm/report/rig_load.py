"""Read what the report and the overlays of a rig need: the output set of ``mvm rig reconstruct``
(``poses3d.jsonl``, ``recap.json``) and the calibration it used; with the rig as the
reconstruction read it (its 2D poses, ``sync.toml`` applied), handed in by the caller
(:func:`mvm.stages.view.load_rig_view`), they make a :class:`RigReportData`. A set whose inputs
changed since it was made is refused in one line naming the command to run.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.core.scene import Poses2D
from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration
from mvm.io.checks import load_json_object
from mvm.io.layout import DEFAULT_OUTPUT, POSES2D, SYNC, RigLayout
from mvm.io.provenance import check_fresh, read_record
from mvm.io.rig_poses3d import RigPoses3D, read_rig_poses3d
from mvm.io.rig_truth import RigTruth, read_rig_truth
from mvm.report.rig_analysis import member_detections

log = logging.getLogger(__name__)


def is_rig_dir(path: str | Path, output: str = DEFAULT_OUTPUT) -> bool:
    """Whether ``path`` is a rig folder rather than a scene directory: it holds a rig's output
    set (``<output>/poses3d.jsonl`` or ``recap.json``), or it has no ``poses2d.json`` but a
    ``pose/`` folder, a ``calibration/`` folder or a ``*.toml`` calibration."""
    layout = RigLayout(path, output)
    if not layout.root.is_dir():
        return False
    if layout.poses3d.exists() or layout.recap.exists():
        return True
    if (layout.root / POSES2D).exists():
        return False
    return layout.pose_dir.is_dir() or layout.calibration_dir.is_dir() \
        or any(p.name.lower() != SYNC for p in layout.root.glob("*.toml"))


@dataclass
class RigReportData:
    """A rig with its reconstruction.

    Attributes:
        rig_dir: the rig folder; out_dir: its output set.
        poses: the persons of ``poses3d.jsonl``; their ``members`` columns follow the cameras of
            ``calibration`` (the order of the calibration).
        calibration: the cameras the reconstruction used (only those with poses); calib: its path.
        detections: the 2D poses (undistorted; ``instant`` indexes ``poses.frames``, -1 for a
            frame without persons); detection: ``(Q, V)`` the pose behind every member (-1: none).
        recap: ``recap.json``; offsets: camera -> frames added (``sync.toml``), or None.
        truth: the truth of a simulated rig (``RIG_DIR.groundtruth.json`` beside it), or None.
    """

    rig_dir: Path
    out_dir: Path
    poses: RigPoses3D
    calibration: RigCalibration
    calib: Path
    detections: Poses2D
    detection: np.ndarray
    recap: dict
    offsets: dict | None
    truth: RigTruth | None = None

    @property
    def names(self) -> list[str]:
        return list(self.calibration.cameras.names)


def _setting(record: dict | None, key: str) -> str | None:
    settings = (record or {}).get("settings")
    value = settings.get(key) if isinstance(settings, dict) else None
    return value if isinstance(value, str) and value else None


def frames_setting(poses3d: Path) -> str | None:
    """The frames (``START:STOP``) the rig reconstruction of ``poses3d`` read, from its record."""
    return _setting(read_record(poses3d), "frames")


def given_calibration(poses3d: Path, calib: str | Path | None) -> Path | None:
    """The calibration given for a page or the overlays of ``poses3d``: ``calib``, else the one
    the reconstruction was given (its record's ``calib`` setting); None: the rig's own."""
    if calib is not None:
        return Path(calib)
    given = _setting(read_record(poses3d), "calib")
    if given is not None:
        if not Path(given).exists():
            raise InputError(poses3d, None, f"made with the calibration {given}, which is not there: "
                                            "give it with --calib")
        return Path(given)
    return None


#: The containers of ``recap.json`` the page reads: field -> (type, what it must be).
_RECAP_SHAPES = {"joint_flags": (dict, "an object"), "excluded_per_camera": (dict, "an object"),
                 "excluded_overall_per_camera": (dict, "an object"), "options": (dict, "an object"),
                 "keypoints": (list, "a list")}


def _checked_recap(path: Path) -> dict:
    """``recap.json``, its containers checked (:data:`_RECAP_SHAPES`): any other shape is one
    :class:`InputError` naming the field."""
    recap = load_json_object(path, what="a rig recap object")
    for field, (kind, what) in _RECAP_SHAPES.items():
        if recap.get(field) is not None and not isinstance(recap[field], kind):
            raise InputError(path, field, f"expected {what}, got {type(recap[field]).__name__}")
    return recap


def rig_command(rig_dir: Path, calib: Path, given: bool, output: str) -> str:
    """The command that makes the rig's output set again, for a refusal to name."""
    return (f"mvm rig reconstruct {rig_dir}" + (f" --calib {calib}" if given else "")
            + ("" if output == DEFAULT_OUTPUT else f" -o {rig_dir / output}"))


def _check_sync(recap: dict, offsets: dict | None, poses3d: Path, command: str) -> None:
    """Refuse a set made with other frame offsets than ``sync.toml`` holds now."""
    before = recap.get("sync_offsets")
    if (before or None) != (offsets or None):
        what = "is new" if not before else "is gone" if not offsets else "changed"
        raise InputError(poses3d, None, f"out of date: sync.toml {what} since the rig reconstruction: "
                                        f"run `{command}` first")


def reconstructed(rig_dir: str | Path, output: str) -> Path:
    """The rig's ``poses3d.jsonl`` in its output set ``output``; refused when there is none."""
    poses3d = RigLayout(rig_dir, output).poses3d
    if not (poses3d.exists() or poses3d.is_symlink()):
        raise InputError(poses3d, None, f"missing: reconstruct the rig first (mvm rig reconstruct {rig_dir})")
    return poses3d


def checked_set(rig_dir: str | Path, output: str, inputs: dict[str, Path], command: str) -> dict:
    """The recap of the rig's output set ``output``, refused in one line naming ``command``
    when the set's inputs (``inputs``: by name, :mod:`mvm.io.provenance`) changed since it was
    made, or when ``recap.json`` is not of the shape the page reads."""
    layout = RigLayout(rig_dir, output)
    check_fresh(reconstructed(rig_dir, output), inputs, command)
    return _checked_recap(layout.recap)


def rig_report_data(rig_dir: str | Path, output: str, rig, calib: Path, recap: dict, command: str) -> RigReportData:
    """The report's data of the rig's output set ``output`` (its recap checked:
    :func:`checked_set`) and ``rig``, the rig as the reconstruction read it
    (:class:`~mvm.rig.rigdir.RigData`: calibration, frames, 2D poses, offsets) from the
    calibration ``calib``. A set made from other poses or offsets is refused naming ``command``."""
    rig_dir = Path(rig_dir)
    layout = RigLayout(rig_dir, output)
    poses3d = layout.poses3d
    _check_sync(recap, rig.offsets, poses3d, command)
    poses = read_rig_poses3d(poses3d)
    names = list(rig.calibration.cameras.names)
    unknown = [c for c in poses.cameras if c not in names]
    if unknown:
        raise InputError(poses3d, "members", f"camera {unknown[0]} is not a camera of {calib} with poses: "
                                             f"out of date? run `{command}`")
    members = np.full((len(poses), len(names)), -1, dtype=np.int64)
    for v, c in enumerate(poses.cameras):
        members[:, names.index(c)] = poses.members[:, v]
    poses.members, poses.cameras = members, names
    det = rig.detections
    frame_of = rig.frames[det.instant]
    at = np.minimum(np.searchsorted(poses.frames, frame_of), len(poses.frames) - 1)
    instant = np.where(poses.frames[at] == frame_of, at, -1)
    detections = Poses2D(det.keypoints, det.view, det.ids, det.score, instant=instant)
    detection = member_detections(poses.members, poses.instant, instant, det.view)
    lost = int(((poses.members >= 0) & (detection < 0)).sum())
    if lost:
        raise InputError(poses3d, "members", f"{lost} members name 2D poses the pose files do not hold: "
                                             f"out of date? run `{command}`")
    log.info("%s: %d instants, %d persons, %d cameras", poses3d, len(poses.frames), len(poses), len(names))
    truth_file = layout.truth
    truth = read_rig_truth(truth_file) if truth_file.is_file() else None
    if truth is not None and set(names) - set(truth.cameras):
        log.warning("%s: not the truth of this rig (no camera %s); not compared", truth_file,
                    sorted(set(names) - set(truth.cameras))[0])
        truth = None
    return RigReportData(rig_dir, layout.out_dir, poses, rig.calibration, calib, detections, detection, recap,
                         rig.offsets, truth)


def in_output_set(path: Path, out_dir: Path) -> bool:
    """Whether ``path`` is an entry at the top of the rig's output set ``out_dir`` (then it is
    listed in the set's marker, :func:`mvm.io.outputs.add_to_output_set`)."""
    return Path(os.path.abspath(path)).parent == Path(os.path.abspath(out_dir))
