"""Read what the report and the overlays of a rig need: the output set of ``mvm rig reconstruct``
(``poses3d.jsonl``, ``recap.json``), the calibration it used, the 2D poses it matched (read as the
reconstruction read them, ``sync.toml`` applied) and the cameras' videos. A set whose inputs
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
from mvm.io.paths import videos_by_name
from mvm.io.provenance import check_fresh, read_record
from mvm.io.rig_poses3d import RigPoses3D, read_rig_poses3d
from mvm.io.rig_truth import RigTruth, read_rig_truth, rig_truth_path
from mvm.report.rig_analysis import member_detections
from mvm.rig.output_set import DEFAULT_OUTPUT
from mvm.rig.reconstruct_rig import rig_fingerprint_inputs
from mvm.rig.rigdir import find_calibration, match_cameras, read_rig

log = logging.getLogger(__name__)

POSES3D = "poses3d.jsonl"
RECAP = "recap.json"
#: Where a rig's videos are: ``RIG_DIR/videos/<camera>.<ext>``.
VIDEOS = "videos"


def is_rig_dir(path: str | Path, output: str = DEFAULT_OUTPUT) -> bool:
    """Whether ``path`` is a rig folder rather than a scene directory: it holds a rig's output
    set (``<output>/poses3d.jsonl`` or ``recap.json``), or it has no ``poses2d.json`` but a
    ``pose/`` folder, a ``calibration/`` folder or a ``*.toml`` calibration."""
    path = Path(path)
    if not path.is_dir():
        return False
    if (path / output / POSES3D).exists() or (path / output / RECAP).exists():
        return True
    if (path / "poses2d.json").exists():
        return False
    return (path / "pose").is_dir() or (path / "calibration").is_dir() \
        or any(p.name.lower() != "sync.toml" for p in path.glob("*.toml"))


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


def used_calibration(rig_dir: Path, poses3d: Path, calib: str | Path | None) -> tuple[Path, bool]:
    """The calibration to read: ``calib``, else the one the reconstruction was given (its
    record's ``calib`` setting), else the rig's own (:func:`mvm.rig.rigdir.find_calibration`);
    and whether it was given (not the rig's own)."""
    if calib is not None:
        return Path(calib), True
    given = _setting(read_record(poses3d), "calib")
    if given is not None:
        if not Path(given).exists():
            raise InputError(poses3d, None, f"made with the calibration {given}, which is not there: "
                                            "give it with --calib")
        return Path(given), True
    return find_calibration(rig_dir), False


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


def _command(rig_dir: Path, calib: Path, given: bool, output: str) -> str:
    return (f"mvm rig reconstruct {rig_dir}" + (f" --calib {calib}" if given else "")
            + ("" if output == DEFAULT_OUTPUT else f" -o {rig_dir / output}"))


def _check_sync(recap: dict, offsets: dict | None, poses3d: Path, command: str) -> None:
    """Refuse a set made with other frame offsets than ``sync.toml`` holds now."""
    before = recap.get("sync_offsets")
    if (before or None) != (offsets or None):
        what = "is new" if not before else "is gone" if not offsets else "changed"
        raise InputError(poses3d, None, f"out of date: sync.toml {what} since the rig reconstruction: "
                                        f"run `{command}` first")


def _reconstructed(rig_dir: Path, output: str) -> Path:
    """The rig's ``poses3d.jsonl`` in its output set ``output``; refused when there is none."""
    poses3d = rig_dir / output / POSES3D
    if not (poses3d.exists() or poses3d.is_symlink()):
        raise InputError(poses3d, None, f"missing: reconstruct the rig first (mvm rig reconstruct {rig_dir})")
    return poses3d


def report_calibration(rig_dir: str | Path, output: str = DEFAULT_OUTPUT, calib: str | Path | None = None) -> Path:
    """The calibration a page or the overlays of the reconstructed rig read
    (:func:`used_calibration`), for checking their output's location before any work; a rig
    not reconstructed is refused first."""
    return used_calibration(Path(rig_dir), _reconstructed(Path(rig_dir), output), calib)[0]


def load_rig_result(rig_dir: str | Path, output: str = DEFAULT_OUTPUT, calib: str | Path | None = None,
                    workers: int | None = None) -> RigReportData:
    """Read a reconstructed rig folder (see the module)."""
    rig_dir = Path(rig_dir)
    out_dir = rig_dir / output
    poses3d = _reconstructed(rig_dir, output)
    calib_path, given = used_calibration(rig_dir, poses3d, calib)
    command = _command(rig_dir, calib_path, given, output)
    check_fresh(poses3d, rig_fingerprint_inputs(rig_dir, calib_path), command)
    recap = _checked_recap(out_dir / RECAP)
    rig = read_rig(rig_dir, calib_path, _setting(read_record(poses3d), "frames"), workers)
    _check_sync(recap, rig.offsets, poses3d, command)
    poses = read_rig_poses3d(poses3d)
    names = list(rig.calibration.cameras.names)
    unknown = [c for c in poses.cameras if c not in names]
    if unknown:
        raise InputError(poses3d, "members", f"camera {unknown[0]} is not a camera of {calib_path} with poses: "
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
    truth_file = rig_truth_path(rig_dir)
    truth = read_rig_truth(truth_file) if truth_file.is_file() else None
    if truth is not None and set(names) - set(truth.cameras):
        log.warning("%s: not the truth of this rig (no camera %s); not compared", truth_file,
                    sorted(set(names) - set(truth.cameras))[0])
        truth = None
    return RigReportData(rig_dir, out_dir, poses, rig.calibration, calib_path, detections, detection, recap,
                         rig.offsets, truth)


def in_output_set(path: Path, out_dir: Path) -> bool:
    """Whether ``path`` is an entry at the top of the rig's output set ``out_dir`` (then it is
    listed in the set's marker, :func:`mvm.io.outputs.add_to_output_set`)."""
    return Path(os.path.abspath(path)).parent == Path(os.path.abspath(out_dir))


def rig_videos(rig_dir: str | Path, names: list[str]) -> dict[str, Path]:
    """The video of each camera that has one: ``RIG_DIR/videos/<camera>.<ext>``, matched to the
    camera names as pose folders are (:func:`mvm.rig.rigdir.match_cameras`)."""
    folder = Path(rig_dir) / VIDEOS
    files = list(videos_by_name(folder).values())
    try:
        matched = match_cameras(names, [p.stem for p in files])
    except ValueError as e:
        raise InputError(folder, None, str(e).replace("pose sources", "videos")) from None
    return {names[c]: files[e] for c, e in sorted(matched.items())}
