"""The shipped pose bank: its frame, its labels, and the functions that build it."""
from __future__ import annotations

import importlib.resources
import re

import numpy as np
import pytest

from mvm.core.keypoints import INDEX, pelvis
from mvm.core.posebank import (
    LABELS,
    PoseBank,
    classify_poses,
    forward_direction,
    load_pose_bank,
    select_distinct,
    to_bank_frame,
)
from mvm.errors import InputError

# A person in the bank frame, facing +y (left side at -x), ankles on z = 0.
STANDING = np.array([
    [0, 0.10, 1.62], [-0.03, 0.08, 1.66], [0.03, 0.08, 1.66], [-0.07, 0.0, 1.64], [0.07, 0.0, 1.64],
    [-0.18, 0, 1.42], [0.18, 0, 1.42], [-0.22, 0.02, 1.13], [0.22, 0.02, 1.13], [-0.24, 0.08, 0.88],
    [0.24, 0.08, 0.88], [-0.10, 0, 0.92], [0.10, 0, 0.92], [-0.11, 0.02, 0.50], [0.11, 0.02, 0.50],
    [-0.11, 0, 0.0], [0.11, 0, 0.0]])


def _sitting() -> np.ndarray:
    """On a chair: thighs horizontal (hips 0.46 m up, knees 0.42 m forward), shanks vertical."""
    pose = STANDING.copy()
    drop = 0.92 - 0.46
    pose[:13, 2] -= drop
    pose[[13, 14]] = [[-0.11, 0.42, 0.46], [0.11, 0.42, 0.46]]
    pose[[15, 16]] = [[-0.11, 0.42, 0.0], [0.11, 0.42, 0.0]]
    return pose


def _crouching() -> np.ndarray:
    """A deep squat: hips 0.30 m up and behind the knees, knees bent to about 60°."""
    pose = STANDING.copy()
    pose[:13, 2] -= 0.92 - 0.30
    pose[:11, 1] += 0.10                                       # trunk leaning forward a little
    pose[[13, 14]] = [[-0.15, 0.30, 0.38], [0.15, 0.30, 0.38]]
    pose[[15, 16]] = [[-0.11, 0.05, 0.0], [0.11, 0.05, 0.0]]
    return pose


def _lying() -> np.ndarray:
    """The standing pose turned to lie along +y."""
    turn = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
    return STANDING @ turn.T


def _yaw(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


@pytest.fixture(scope="module")
def bank() -> PoseBank:
    return load_pose_bank()


def test_shipped_bank_shape_and_content(bank):
    assert 1500 <= len(bank) <= 3000
    assert bank.poses.dtype == np.float32 and bank.poses.shape == (len(bank), 17, 3)
    assert set(bank.labels.tolist()) <= set(LABELS)
    counts = {label: int((bank.labels == label).sum()) for label in LABELS}
    assert counts["standing"] > 100 and counts["sitting"] > 20 and counts["crouching"] > 10, counts
    pattern = re.compile(r"^(\d\d_\d\d:\d+|panoptic:\d{6}:\d+)$")
    assert all(pattern.match(s) for s in bank.sources)
    assert len(set(bank.sources.tolist())) == len(bank)
    assert bank.complete.sum() >= len(bank) - 60          # only some Panoptic bodies lack joints
    assert any(s.startswith("panoptic:") for s in bank.sources)


def test_shipped_bank_is_in_the_documented_frame(bank):
    poses = bank.poses.astype(float)
    np.testing.assert_allclose(np.nanmin(poses[:, [15, 16], 2], axis=1), 0.0, atol=1e-5)
    np.testing.assert_allclose(pelvis(poses)[:, :2], 0.0, atol=1e-5)
    # facing +y: the hip axis (right -> left) points to -x, without a y component
    hip_axis = poses[:, INDEX["left_hip"]] - poses[:, INDEX["right_hip"]]
    assert np.all(hip_axis[:, 0] < 0)
    np.testing.assert_allclose(hip_axis[:, 1], 0.0, atol=1e-5)
    np.testing.assert_allclose(forward_direction(poses), np.broadcast_to([0.0, 1.0], (len(poses), 2)), atol=1e-5)
    # z is up: standing people have the head about 1.4-1.9 m above the ankles
    standing = poses[bank.labels == "standing"]
    head = standing[:, INDEX["nose"], 2]
    assert 1.35 < np.median(head) < 1.9
    # the bank's standing people face +y: the nose is in front of the ears
    ears = 0.5 * (standing[:, INDEX["left_ear"]] + standing[:, INDEX["right_ear"]])
    assert np.mean(standing[:, INDEX["nose"], 1] > ears[:, 1]) > 0.95


def test_shipped_bank_poses_are_distinct(bank):
    resource = importlib.resources.files("mvm").joinpath("data/pose_bank.npz")
    with importlib.resources.as_file(resource) as path, np.load(path) as data:
        min_distance = float(data["min_distance_m"])
    assert 0.02 <= min_distance <= 0.2
    cmu = bank.poses[~np.char.startswith(bank.sources.astype(str), "panoptic")][:500].astype(float)
    d = np.linalg.norm(cmu[:, None] - cmu[None], axis=-1).mean(axis=-1)
    np.fill_diagonal(d, np.inf)
    assert d.min() >= min_distance - 1e-5          # float32 storage


def test_to_bank_frame_undoes_a_turn_and_a_shift():
    rng = np.random.default_rng(3)
    for _ in range(10):
        moved = (STANDING @ _yaw(rng.uniform(-np.pi, np.pi)).T
                 + [rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-1, 1)])
        np.testing.assert_allclose(to_bank_frame(moved[None])[0], STANDING, atol=1e-12)


def test_to_bank_frame_without_hips_or_ankles_is_nan():
    poses = np.stack([STANDING, STANDING, STANDING])
    poses[0, INDEX["left_hip"]] = np.nan
    poses[1, [15, 16]] = np.nan
    poses[2, 15] = np.nan                                      # one ankle is enough
    out = to_bank_frame(poses)
    assert np.isnan(out[:2]).all()
    np.testing.assert_allclose(out[2, 16], STANDING[16], atol=1e-12)


def test_classify_constructed_poses():
    poses = np.stack([STANDING, _sitting(), _crouching(), _lying()])
    assert classify_poses(poses).tolist() == ["standing", "sitting", "crouching", "other"]
    # labels do not depend on the heading
    assert classify_poses(poses @ _yaw(1.0).T).tolist() == ["standing", "sitting", "crouching", "other"]


def test_select_distinct_keeps_a_spread_subset():
    rng = np.random.default_rng(0)
    offsets = rng.uniform(0, 1.0, 200)
    poses = STANDING[None] + offsets[:, None, None] * np.array([1.0, 0, 0])   # mean joint distance = |Δoffset|
    kept = select_distinct(poses, 0.1, chunk=16)
    gaps = np.abs(offsets[kept][:, None] - offsets[kept][None])
    np.fill_diagonal(gaps, np.inf)
    assert kept[0] == 0 and gaps.min() >= 0.1 - 1e-12
    dropped = np.setdiff1d(np.arange(200), kept)
    for i in dropped:                                          # each dropped pose is near an earlier kept one
        earlier = kept[kept < i]
        assert np.abs(offsets[earlier] - offsets[i]).min() < 0.1
    np.testing.assert_array_equal(select_distinct(poses, 0.1, chunk=7), kept)  # chunking does not matter
    assert 5 <= len(kept) <= 11


def test_pose_bank_checks_and_reads(tmp_path, bank):
    with pytest.raises(ValueError, match="unknown labels"):
        PoseBank(np.zeros((1, 17, 3)), np.array(["flying"]), np.array(["x"]))
    path = tmp_path / "bank.npz"
    np.savez(path, poses=bank.poses[:3], labels=bank.labels[:3], sources=bank.sources[:3])
    small = load_pose_bank(path)
    np.testing.assert_array_equal(small.poses, bank.poses[:3])
    assert small.subset(small.labels == small.labels[0]).labels.tolist().count(small.labels[0]) >= 1
    np.savez(path, poses=bank.poses[:3])
    with pytest.raises(InputError, match="labels"):
        load_pose_bank(path)
    with pytest.raises(InputError, match="file not found"):
        load_pose_bank(tmp_path / "absent.npz")
