"""Calib.toml: Pose2Sim's published layout read, round trip, clear errors."""
import dataclasses

import cv2
import numpy as np
import pytest

from mvm.core.scene import Cameras
from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration, read_calib_toml, write_calib_toml

# As Pose2Sim's calibration writes it (toml.dump layout: trailing commas, [metadata] last).
POSE2SIM = """[int_cam01_img]
name = "int_cam01_img"
size = [ 1088.0, 1920.0,]
matrix = [ [ 1681.1, 0.0, 538.2,], [ 0.0, 1682.2, 956.1,], [ 0.0, 0.0, 1.0,],]
distortions = [ -0.05, 0.12, -0.001, 0.002,]
rotation = [ 1.6, 0.9, -0.7,]
translation = [ 0.39, 0.79, 2.37,]
fisheye = false

[int_cam02_img]
name = "int_cam02_img"
size = [ 1088.0, 1920.0,]
matrix = [ [ 1700.0, 0.0, 540.0,], [ 0.0, 1700.0, 960.0,], [ 0.0, 0.0, 1.0,],]
distortions = [ 0.0, 0.0, 0.0, 0.0,]
rotation = [ 0.1, -2.0, 0.3,]
translation = [ -0.2, 0.5, 3.1,]
fisheye = false

[metadata]
adjusted = false
error = 0.0
"""


def test_read_pose2sim_layout(tmp_path):
    path = tmp_path / "Calib.toml"
    path.write_text(POSE2SIM)
    calib = read_calib_toml(path)
    assert calib.cameras.names == ("int_cam01_img", "int_cam02_img")
    assert calib.cameras.K[0, 0, 2] == pytest.approx(538.2)
    np.testing.assert_allclose(calib.cameras.R[0], cv2.Rodrigues(np.array([1.6, 0.9, -0.7]))[0])
    np.testing.assert_allclose(calib.cameras.t[1], [-0.2, 0.5, 3.1])
    np.testing.assert_allclose(calib.distortions[0], [-0.05, 0.12, -0.001, 0.002])
    assert calib.metadata == {"adjusted": False, "error": 0.0}
    np.testing.assert_allclose(calib.cameras.size[0], [1088, 1920])


def test_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    R = np.stack([cv2.Rodrigues(rng.normal(size=3))[0] for _ in range(3)])
    K = np.tile(np.array([[1500.0, 0, 960], [0, 1510, 540], [0, 0, 1]]), (3, 1, 1))
    cams = Cameras(K, R, rng.normal(size=(3, 3)), np.tile([1920.0, 1080], (3, 1)), ("cam_2", "cam_10", "cam 1"))
    calib = RigCalibration(dataclasses.replace(
        cams, distortion=(np.array([-0.1, 0.02, 0.001, 0.0]), np.zeros(5), np.array([0.1, 0, 0, 0.01])),
        fisheye=np.array([False, False, True])), {"adjusted": True, "error": 0.25})
    write_calib_toml(tmp_path / "c.toml", calib)
    back = read_calib_toml(tmp_path / "c.toml")
    assert back.cameras.names == cams.names
    for name in ("K", "R", "t", "size"):
        np.testing.assert_allclose(getattr(back.cameras, name), getattr(cams, name), atol=1e-9)
    for a, b in zip(back.distortions, calib.distortions):
        np.testing.assert_allclose(a, b)
    assert back.fisheye.tolist() == [False, False, True]
    assert back.metadata == {"adjusted": True, "error": 0.25}


def test_errors_name_table_and_key(tmp_path):
    path = tmp_path / "Calib.toml"
    path.write_text(POSE2SIM.replace("translation = [ 0.39, 0.79, 2.37,]", "translation = [ 0.39, 0.79,]"))
    with pytest.raises(InputError, match=r"\[int_cam01_img\]\.translation: expected shape \(3,\)"):
        read_calib_toml(path)
    path.write_text("[metadata]\nadjusted = false\n")
    with pytest.raises(InputError, match="no camera table"):
        read_calib_toml(path)
