"""The real 4-camera capture (``real_footage``) through the rig commands a user runs, default
settings: the lab's Qualisys calibration converted, the cameras synchronized, the board photos'
intrinsics, the extrinsics from the people, the reconstruction and the report. The 2D poses are
the detections of the capture's YOLO11n-pose model by Ultralytics' own code (mvm's detector on
the same model is tested against them in ``tests/video/test_yolo_pose.py``). The lab's
calibration is the reference."""
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.main import main
from mvm.io.rig_poses3d import read_rig_poses3d
from mvm.io.sync_toml import read_sync_toml
from mvm.metrics.poses import similarity_transform
from mvm.metrics.tracks import limb_length_std
from mvm.rig.rigdir import read_calibration

from helpers import SHARED_DATA

REAL = SHARED_DATA / "real_footage"


def _run(*args) -> None:
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exit_code == 0, result.output


def _main_track(out) -> tuple[int, np.ndarray]:
    """The instants of the longest track and its joints ``(T, 17, 3)`` (NaN elsewhere)."""
    rec = read_rig_poses3d(out / "poses3d.jsonl")
    tracks, counts = np.unique(rec.track, return_counts=True)
    rows = np.flatnonzero(rec.track == tracks[np.argmax(counts)])
    X = np.full((len(rec.frames), 17, 3), np.nan)
    X[rec.instant[rows]] = rec.X[rows]
    return int(counts.max()), X


def _centre_errors_m(calib, reference) -> np.ndarray:
    est, ref = read_calibration(calib).cameras, read_calibration(reference).cameras
    centres = est.centers[[est.names.index(n) for n in ref.names]]
    s, R, t = similarity_transform(centres, ref.centers)
    return np.linalg.norm(s * centres @ R.T + t - ref.centers, axis=1)


@pytest.mark.slow
def test_the_real_capture_from_its_raw_material(tmp_path):
    if not (REAL / "pose_ultralytics").is_dir() or not (REAL / "calibration" / "Calib.qca.txt").is_file():
        pytest.skip(f"real capture absent: {REAL}")
    rig = tmp_path / "rig"
    (rig / "pose").mkdir(parents=True)
    for f in sorted((REAL / "pose_ultralytics").glob("cam*.json")):
        shutil.copy(f, rig / "pose" / f.name)
    (rig / "calibration").mkdir()
    (rig / "calibration" / "intrinsics").symlink_to(REAL / "calibration" / "intrinsics")
    lab = tmp_path / "lab.toml"
    _run("rig", "calibrate", rig, "--convert", REAL / "calibration" / "Calib.qca.txt", "-o", lab)

    # The lab's calibration, frame numbers as they are: one track over every instant, steady bones.
    _run("rig", "reconstruct", rig, "--calib", lab, "-o", tmp_path / "lab_out")
    instants, X = _main_track(tmp_path / "lab_out")
    assert instants >= 98
    assert 1000 * np.nanmean(limb_length_std(X)) <= 10.0

    # Synchronized from the people: the lab's cameras are synchronized to about 3 frames.
    _run("rig", "synchronize", rig, "--calib", lab)
    offsets = read_sync_toml(rig / "sync.toml")
    assert max(abs(v) for v in offsets.values()) <= 3, offsets

    # Intrinsics from the board photos, extrinsics from the people, then the reconstruction.
    board = tmp_path / "board.toml"
    _run("rig", "calibrate", rig, "--checkerboard", "--intrinsics-only", "--board-size", "4x7",
         "--square-size", "0.06", "-o", board)
    people = tmp_path / "people.toml"
    _run("rig", "calibrate", rig, "--from-people", "--intrinsics", board, "-o", people)
    error = _centre_errors_m(people, lab)
    assert error.mean() <= 0.100 and error.max() <= 0.150, error
    _run("rig", "reconstruct", rig, "--calib", people)
    instants, X = _main_track(rig / "mvm")
    assert instants >= 95
    assert 1000 * np.nanmean(limb_length_std(X)) <= 15.0
    _run("report", rig)
    assert (rig / "mvm" / "report.html").stat().st_size > 0
