"""Calibration from people on the real capture (``real_footage``: 4 cameras of a mocap lab, one
person balancing, a bystander standing still seen by two cameras, 2D poses of a nano model):
the camera centres against the lab's marker-based calibration, after the best similarity, with
the lab's focal lengths and with them 1 % off; the lab's extrinsics are never read."""
import dataclasses
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.rig import rig
from mvm.io.calib_toml import RigCalibration, calib_toml_text, read_calib_toml
from mvm.io.rig_simulation import intrinsics_only_text
from mvm.metrics.poses import similarity_transform

from helpers import SHARED_DATA

REAL = SHARED_DATA / "real_footage"
LAB = REAL / "calibration" / "Calib_converted_by_pose2sim.toml"


@pytest.mark.slow
@pytest.mark.parametrize("focal_error", [0.0, 0.01, -0.01])
def test_real_capture_cameras_within_10_cm_of_the_lab(tmp_path, focal_error):
    if not LAB.is_file() or not (REAL / "pose_ultralytics").is_dir():
        pytest.skip(f"real capture absent: {REAL}")
    root = tmp_path / "rig"
    (root / "pose").mkdir(parents=True)
    for f in (REAL / "pose_ultralytics").glob("cam*.json"):
        shutil.copy(f, root / "pose" / f.name)
    lab = read_calib_toml(LAB)
    K = lab.cameras.K.copy()
    K[:, :2, :2] *= (1 + focal_error * np.where(np.arange(len(K)) % 2 == 0, 1.0, -1.0))[:, None, None]
    given = RigCalibration(dataclasses.replace(lab.cameras, K=K))
    intrinsics = tmp_path / "intrinsics.toml"
    intrinsics.write_text(intrinsics_only_text(calib_toml_text(given)))             # no rotation, no translation
    out = tmp_path / "people.toml"
    result = CliRunner().invoke(rig, ["calibrate", str(root), "--from-people", "-o", str(out),
                                      "--intrinsics", str(intrinsics)])
    assert result.exit_code == 0, result.output
    found = read_calib_toml(out).cameras
    s, R, t = similarity_transform(found.centers, lab.cameras.centers)
    error = np.linalg.norm(s * found.centers @ R.T + t - lab.cameras.centers, axis=1)
    assert error.mean() <= 0.100 and error.max() <= 0.150, error
    assert "position_sd_m" in out.read_text()
