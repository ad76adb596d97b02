"""Numbers that overflow or lose precision, and messages that name the file and the problem:
the JSON writer policy (finite or null, relative precision), bounded frame numbers, huge
appearance descriptors, and the rig's pose files (read inside the rig, named in errors)."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from mvm.core.affinity import appearance_similarity
from mvm.core.scene import Persons3D, Poses2D
from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration, write_calib_toml
from mvm.io.coco import coco_keypoints_document, read_coco_keypoints
from mvm.io.files import json_number
from mvm.io.openpose import MAX_FRAME, frame_number
from mvm.io.scene_dir import poses3d_document, read_poses3d, write_poses3d
from mvm.rig.rigdir import read_rig
from mvm.sim.rig import ring_cameras

from helpers import standing_poses


def test_json_number_policy():
    assert json_number(float("nan")) is None and json_number(float("inf")) is None
    assert json_number(1.23456789012345e-7) == 1.234567890e-7
    assert json_number(123456.789012345) == 123456.789
    assert json_number(2.0) == 2.0


@pytest.mark.parametrize("unit_m", [1e-5, 1.0, 1e5])
def test_poses3d_keeps_relative_precision_in_any_unit(tmp_path, unit_m):
    """A model whose unit is ``unit_m`` metres: coordinates are metres / unit_m."""
    X = standing_poses(2, seed=3) / unit_m
    persons = Persons3D(X, np.full((2, 17), 0.8), [np.array([0]), np.array([1])], np.full((2, 17), 2),
                        np.zeros((2, 17), int), np.array([1.5, np.nan]))
    poses = Poses2D(np.zeros((2, 17, 3)), np.arange(2), np.arange(1, 3), np.ones(2), None)
    path = tmp_path / "poses3d.json"
    write_poses3d(path, poses3d_document(persons, poses, {"E_R_px": float("nan"), "persons": 2}))
    back = read_poses3d(path)
    error_m = np.abs(back.keypoints3d - X).max() * unit_m
    assert error_m < 1e-8                                   # 6 fixed decimals lost 50 mm at 1e5
    document = json.loads(path.read_text())
    assert document["metrics"]["E_R_px"] is None and document["persons"][1]["reprojection_error_px"] is None


@pytest.mark.parametrize("digits, ok", [("000000000012", True), ("999999999", True), ("1" * 30, False),
                                        ("7" * 5000, False)])
def test_frame_numbers_are_bounded(digits, ok):
    name = f"cam1_{digits}_keypoints.json"
    if ok:
        assert frame_number(name) == int(digits) <= MAX_FRAME
    else:
        with pytest.raises(InputError,
                           match=r"frame number \d+.* in the file name is out of range \(at most 999999999\)"):
            frame_number(name)


def test_huge_appearance_descriptors_still_match(tmp_path):
    """Descriptors of 1e308 would make every cosine similarity NaN (0 persons): they are
    rescaled exactly, and the similarities equal those of the unscaled descriptors."""
    rng = np.random.default_rng(0)
    base = rng.uniform(0.1, 1.0, (4, 8))
    scale = np.array([1e308, 1.0, 1e-300, 3.0])[:, None]
    doc = coco_keypoints_document(["a.jpg", "b.jpg"], np.full((2, 2), 100), np.array([0, 0, 1, 1]),
                                  np.ones((4, 17, 3)), np.ones(4), appearance=base)
    for ann, s in zip(doc["annotations"], scale[:, 0]):
        ann["appearance"] = (np.array(ann["appearance"]) * s).tolist()
    path = tmp_path / "poses2d.json"
    path.write_text(json.dumps(doc))
    appearance = read_coco_keypoints(path).appearance
    assert np.isfinite(appearance).all()
    expected = appearance_similarity(np.round(base, 5), 4)
    assert np.allclose(appearance_similarity(appearance, 4), expected, atol=1e-6)


# ------------------------------------------------------------------------------- the rig's files


def _rig(root, names=("cam_1", "cam_2")):
    cameras = ring_cameras(len(names), names=names)
    write_calib_toml(root / "Calib.toml",
                     RigCalibration(dataclasses.replace(cameras, distortion=tuple(np.zeros(4) for _ in names))))
    (root / "pose").mkdir()
    kp = np.zeros((17, 3))
    kp[:, :2], kp[:, 2] = 100.0 + np.arange(17)[:, None], 0.9
    for name in names:
        doc = coco_keypoints_document([f"{name}_000001.jpg", f"{name}_000002.jpg"], np.full((2, 2), 1000),
                                      np.array([0, 1]), np.stack([kp, kp]), np.full(2, 0.9))
        (root / "pose" / f"{name}.json").write_text(json.dumps(doc))
    return root


def test_rig_pose_file_names_without_frame_numbers_name_the_pose_file(tmp_path):
    root = _rig(tmp_path)
    assert read_rig(root).frames.tolist() == [1, 2]
    path = root / "pose" / "cam_2.json"
    doc = json.loads(path.read_text())
    doc["images"][1]["file_name"] = "still.jpg"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError) as info:
        read_rig(root)
    assert str(info.value) == f"{path}: images[1].file_name: no frame number in the file name 'still.jpg'"


def test_rig_pose_file_linked_outside_is_refused(tmp_path):
    root = _rig(tmp_path / "rig")
    outside = tmp_path / "elsewhere.json"
    (root / "pose" / "cam_1.json").rename(outside)
    (root / "pose" / "cam_1.json").symlink_to(outside)
    with pytest.raises(InputError, match=r"cam_1.json: leads outside .*rig through a symbolic link"):
        read_rig(root)
