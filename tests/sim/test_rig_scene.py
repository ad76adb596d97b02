"""The simulated rig: the frame-offset convention, real motion, the folder it writes."""
import json

import numpy as np
import pytest

from mvm.core.keypoints import NUM_JOINTS
from mvm.errors import InputError
from mvm.io.calib_toml import read_calib_toml
from mvm.io.rig_simulation import write_rig_simulation
from mvm.rig.rigdir import read_rig
from mvm.sim.detector import DetectorErrors
from mvm.sim.rig_scene import ARM_BONES, RigSimConfig, moving_people, simulate_rig

EXACT = DetectorErrors(noise=0.0, dropout=0.0, occlusion=False, swap_prob=0.0, outlier_joint_prob=0.0,
                       false_pose_rate=0.0)


def test_offsets_convention_camera_frame_shows_instant_plus_offset():
    offsets = (0, 3, -2)
    sim = simulate_rig(RigSimConfig(cameras=3, people=2, frames=12, offsets=offsets, errors=EXACT, distortion=0.0))
    assert sim.sync_offsets.tolist() == [0, 3, -2]
    cams = sim.calibration.cameras
    for c in range(3):
        for f in (0, 7, 11):
            s = f + offsets[c] - sim.instants[0]                              # index of the instant f + offset
            X = np.concatenate([sim.poses3d[s], np.ones((2, NUM_JOINTS, 1))], -1) @ cams.P[c].T
            uv = X[..., :2] / X[..., 2:]
            kp = sim.keypoints[(sim.camera == c) & (sim.frame == f)]
            assert len(kp) == 2
            err = np.abs(kp[:, None, :, :2] - uv[None]).max(axis=(2, 3))   # (detected, true)
            assert err.min(axis=1).max() < 1e-6


def test_moving_people_move_like_people():
    X = moving_people(3, 60, np.random.default_rng(0))
    assert X.shape == (60, 3, NUM_JOINTS, 3) and np.isfinite(X).all()
    step = np.linalg.norm(np.diff(X, axis=0), axis=-1)                        # m per frame at 30 Hz
    assert 0.005 < step.mean() < 0.08 and step.max() < 0.3              # no jumps
    assert (X[..., 2].min(-1) > -0.05).all() and (X[..., 2].max(-1) > 1.2).mean() > 0.8   # on the floor, mostly up


def test_played_motions_keep_their_arms_lengths():
    """The bank's poses are a few source frames apart; interpolated linearly between two of them a
    swinging forearm shrank (to 0.15 m of 0.25 in seed 0). Played, every arm bone keeps the
    length it has in the bank's poses (rigid there)."""
    sim = simulate_rig(RigSimConfig(cameras=2, people=3, frames=150, seed=0, errors=EXACT))
    arms = np.linalg.norm(sim.poses3d[:, :, ARM_BONES[:, 1]] - sim.poses3d[:, :, ARM_BONES[:, 0]], axis=-1)
    assert np.abs(arms / np.median(arms, axis=0) - 1).max() < 1e-6


def test_rig_folder_and_truth(tmp_path):
    sim = simulate_rig(RigSimConfig(cameras=3, people=2, frames=10, offsets=(0, 1, -1)))
    paths = write_rig_simulation(tmp_path / "rig", sim, intrinsics_only=True)
    truth = json.loads(paths["truth"].read_text())
    assert truth["sync_offsets"] == {"cam_01": 0, "cam_02": 1, "cam_03": -1}
    assert np.array(truth["poses3d"]).shape == sim.poses3d.shape
    with pytest.raises(InputError, match=r"rotation.*missing"):
        read_calib_toml(paths["calibration"])
    intrinsics = read_calib_toml(paths["calibration"], extrinsics=False)
    assert np.isnan(intrinsics.cameras.R).all() and np.allclose(intrinsics.cameras.K, sim.calibration.cameras.K)
    full = read_calib_toml(paths["true_calibration"])
    assert np.allclose(full.cameras.R, sim.calibration.cameras.R)
    rig = read_rig(tmp_path / "rig", extrinsics=False)
    assert rig.pose_format == "coco" and len(rig.detections) == len(sim.keypoints) and rig.offsets is None


def test_offsets_longer_than_the_videos_refused():
    with pytest.raises(ValueError, match="offsets"):
        RigSimConfig(cameras=2, frames=10, offsets=(0, 10))
