"""Rig directory end to end: Calib.toml with lens distortion, OpenPose folders matched by name,
the `rig reconstruct` command, JSON Lines and .trc outputs checked against the truth."""
import dataclasses
import json

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.rig import rig
from mvm.core.keypoints import COCO_KEYPOINTS
from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration, write_calib_toml
from mvm.io.openpose import BODY25_TO_COCO17
from mvm.io.trc import read_trc, to_opensim
from mvm.rig.rigdir import match_cameras, read_rig
from mvm.sim.rig import DetectorErrors, detect_views, ring_cameras, walking_people

NAMES = ("cam_1", "cam_2", "cam_10", "cam_3", "cam_4")   # string order would put cam_10 second
DIST = np.array([-0.12, 0.05, 0.001, -0.0005])


def _write_rig(root, T=8, seed=0):
    cameras = ring_cameras(len(NAMES), names=NAMES)
    rng = np.random.default_rng(seed)
    truth = walking_people(2, T, rng)
    dist = tuple(DIST * (i + 1) / len(NAMES) for i in range(len(NAMES)))
    cameras = dataclasses.replace(cameras, distortion=dist)
    write_calib_toml(root / "Calib.toml", RigCalibration(cameras))
    errors = DetectorErrors(noise=0.004, false_pose_rate=0.0, swap_prob=0.0, outlier_joint_prob=0.0)
    for t in range(T):
        kp, cam, _ = detect_views(cameras, truth[t], rng, errors)
        for v, name in enumerate(NAMES):
            folder = root / "pose" / f"{name.replace('_', '')}_json"        # "cam10_json": matched by number
            folder.mkdir(parents=True, exist_ok=True)
            people = []
            for k in kp[cam == v]:
                body25 = np.zeros((25, 3))
                body25[BODY25_TO_COCO17] = k
                people.append({"person_id": [-1], "pose_keypoints_2d": body25.reshape(-1).tolist()})
            (folder / f"{name}_{t:012d}_keypoints.json").write_text(json.dumps({"version": 1.3, "people": people}))
    return cameras, truth


def test_match_cameras_by_name_not_order():
    assert match_cameras(["cam_1", "cam_2", "cam_10"], ["cam10_json", "cam1_json", "cam2_json"]) == {0: 1, 1: 2, 2: 0}
    assert match_cameras(["left", "right"], ["right", "left", "other"]) == {0: 1, 1: 0}
    with pytest.raises(ValueError, match="several"):
        match_cameras(["cam_1"], ["CAM_1", "cam_1_json"])


def test_read_rig_undistorts(tmp_path):
    cameras, truth = _write_rig(tmp_path, T=2)
    data = read_rig(tmp_path)
    assert data.calibration.cameras.names == NAMES and data.pose_format == "openpose"
    assert data.frames.tolist() == [0, 1]
    assert data.sources["cam_10"].name == "cam10_json"
    # undistorted keypoints lie close to the pinhole projection of the truth (noise 0.4 %)
    det = data.detections
    v = 2
    rows = (det.instant == 0) & (det.view == v)
    x = np.concatenate([truth[0], np.ones((2, 17, 1))], -1) @ cameras.P[v].T
    uv = x[..., :2] / x[..., 2:]
    kp = det.keypoints[rows]
    err = np.linalg.norm(kp[:, None, :, :2] - uv[None], axis=-1)          # (n, 2, 17)
    best = np.where(kp[:, None, :, 2] > 0, err, np.nan)
    assert np.nanmin(np.nanmean(best, -1), 1).max() < 10.0


def test_rig_reconstruct_command(tmp_path):
    cameras, truth = _write_rig(tmp_path, T=8)
    result = CliRunner().invoke(rig, ["reconstruct", str(tmp_path), "--no-refine", "--smoothing", "savgol",
                                      "--rig-set", "savgol_window=5"])
    assert result.exit_code == 0, result.output
    lines = (tmp_path / "mvm" / "poses3d.jsonl").read_text().splitlines()
    assert len(lines) == 8
    first = json.loads(lines[0])
    assert first["frame"] == 0 and len(first["persons"]) == 2
    recap = json.loads((tmp_path / "mvm" / "recap.json").read_text())
    assert recap["tracks"] == 2 and len(recap["error_per_keypoint_px"]) == 17
    assert set(recap["excluded_per_camera"]) == set(NAMES)
    trcs = sorted((tmp_path / "mvm" / "tracks").glob("*.trc"))
    assert len(trcs) == 2
    for path in trcs:
        trc = read_trc(path)
        assert trc.points.shape == (8, 17, 3) and trc.markers == COCO_KEYPOINTS
        expected = to_opensim(truth[:, :, :, :], "+z")                     # (T, G, 17, 3), metres, Y up
        err = np.nanmean(np.linalg.norm(trc.points[:, None] - expected, axis=-1), axis=(0, 2))
        assert err.min() < 0.05                                            # one true person, within 5 cm


def test_missing_calibration_is_one_line(tmp_path):
    (tmp_path / "pose" / "cam_1").mkdir(parents=True)
    with pytest.raises(InputError, match="no calibration"):
        read_rig(tmp_path)
