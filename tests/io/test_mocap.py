"""ASF/AMC and Panoptic readers: hand-computed forward kinematics, real-data sanity, clear errors."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mvm.core.keypoints import INDEX, MEAN_BONE_LENGTHS_M, bone_lengths
from mvm.errors import InputError
from mvm.io.mocap import (
    INCH_M,
    asf_to_coco17,
    euler_matrices,
    forward_kinematics,
    read_amc,
    read_asf,
    read_panoptic_coco19,
    read_panoptic_ids,
)

from helpers import SHARED_DATA  # noqa: E402

CMU = SHARED_DATA / "cmu_mocap"
PANOPTIC = SHARED_DATA / "panoptic" / "160906_band1" / "hdPose3d_stage1_coco19"

# Lengths in inches (:units length 1.0), so that metres = value * 0.0254.
TINY_ASF = """\
# a three-bone chain
:version 1.10
:name tiny
:units
  mass 1.0
  length 1.0
  angle deg
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name a
     direction 0 2 0
     length 10
     axis 0 0 0  XYZ
    dof rx ry rz
    limits (-180.0 180.0)
           (-180.0 180.0)
           (-180.0 180.0)
  end
  begin
     id 2
     name b
     direction 1 0 0
     length 5
     axis 0 0 90 XYZ
    dof rx
    limits (-180.0 180.0)
  end
  begin
     id 3
     name c
     direction 0 1 0
     length 4
     axis 0 0 0 XYZ
    dof rz rx
    limits (-180.0 180.0)
           (-180.0 180.0)
  end
:hierarchy
  begin
    root a
    a b
    root c
  end
"""

# Frame 1: root at (10, 20, 30) turned 90° about y; a: 90° about x; b: 90° about its axis;
# c: rz = 90, rx = 90 (values listed in the dof order "rz rx"). Frame 2: everything at rest.
TINY_AMC = """\
# comment
:FULLY-SPECIFIED
:DEGREES
1
root 10 20 30 0 90 0
a 90 0 0
b 90
c 90 90
2
root 0 0 0 0 0 0
a 0 0 0
b 0
c 0 0
"""


@pytest.fixture
def tiny(tmp_path):
    (tmp_path / "tiny.asf").write_text(TINY_ASF)
    (tmp_path / "tiny.amc").write_text(TINY_AMC)
    return read_asf(tmp_path / "tiny.asf"), read_amc(tmp_path / "tiny.amc")


def test_euler_order_xyz_applies_x_first():
    r = euler_matrices(np.radians([90.0, 0.0, 90.0]), "XYZ")
    # Rz(90) · Rx(90) · e_y = Rz(90) · e_z = e_z (the other order would give -e_x)
    np.testing.assert_allclose(r @ [0, 1, 0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(euler_matrices(np.radians([90.0, 0.0, 90.0]), "ZYX") @ [0, 1, 0], [-1, 0, 0], atol=1e-12)


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_euler_matrices_match_scipy(order):
    from scipy.spatial.transform import Rotation

    angles = np.random.default_rng(0).uniform(-np.pi, np.pi, (5, 3))        # about x, y, z
    in_order = angles[:, ["XYZ".index(a) for a in order]]
    expected = Rotation.from_euler(order.lower(), in_order).as_matrix()       # extrinsic: fixed axes
    np.testing.assert_allclose(euler_matrices(angles, order), expected, atol=1e-12)


def test_tiny_skeleton_is_parsed(tiny):
    skeleton, frames = tiny
    assert skeleton.names == ("root", "a", "c", "b")          # parents before children
    assert skeleton.parents.tolist() == [-1, 0, 0, 1]
    np.testing.assert_allclose(skeleton.lengths, np.array([0, 10, 4, 5]) * INCH_M)
    np.testing.assert_allclose(skeleton.directions[1], [0, 1, 0])   # normalized
    assert skeleton.dofs[skeleton.index("c")] == ("rz", "rx")
    assert len(frames) == 2 and frames[0]["c"] == (90.0, 90.0)


def test_forward_kinematics_matches_hand_computation(tiny):
    skeleton, frames = tiny
    positions, rotations = forward_kinematics(skeleton, frames)
    s = INCH_M
    root = np.array([10, 20, 30]) * s
    # a: R_root · Rx(90) · (0, 10, 0) = Ry(90) · (0, 0, 10) = (10, 0, 0)
    a_end = root + np.array([10, 0, 0]) * s
    # b: C = Rz(90), so its rx turns about the global y axis: local = Ry(90);
    # Ry(90) · Rx(90) · Ry(90) · (5, 0, 0) = Ry(90) · Rx(90) · (0, 0, -5) = Ry(90) · (0, 5, 0) = (0, 5, 0)
    b_end = a_end + np.array([0, 5, 0]) * s
    # c: rz = 90 and rx = 90 composed in the axis order XYZ: Rz · Rx · (0, 4, 0) = (0, 0, 4), then Ry(90): (4, 0, 0)
    c_end = root + np.array([4, 0, 0]) * s
    i = {name: skeleton.index(name) for name in ("root", "a", "b", "c")}
    np.testing.assert_allclose(positions[0, i["root"]], root, atol=1e-12)
    np.testing.assert_allclose(positions[0, i["a"]], a_end, atol=1e-12)
    np.testing.assert_allclose(positions[0, i["b"]], b_end, atol=1e-12)
    np.testing.assert_allclose(positions[0, i["c"]], c_end, atol=1e-12)
    # rest frame: bones along their directions
    np.testing.assert_allclose(positions[1, i["b"]], np.array([5, 10, 0]) * s, atol=1e-12)
    np.testing.assert_allclose(rotations[1], np.broadcast_to(np.eye(3), (4, 3, 3)), atol=1e-12)
    # global rotations are proper rotations
    np.testing.assert_allclose(rotations[0] @ np.swapaxes(rotations[0], -1, -2), np.broadcast_to(np.eye(3), (4, 3, 3)), atol=1e-12)


@pytest.mark.parametrize("old, new, where", [
    ("length 10", "length ten", "line 18"),
    ("dof rx\n", "dof rq\n", "line 31"),
    ("    a b\n", "    a nosuchbone\n", "line 47"),
    ("axis 0 0 90 XYZ", "axis 0 0 90 XXY", "line 30"),
])
def test_malformed_asf_names_the_line(tmp_path, old, new, where):
    path = tmp_path / "bad.asf"
    assert old in TINY_ASF
    path.write_text(TINY_ASF.replace(old, new))
    with pytest.raises(InputError) as error:
        read_asf(path)
    assert str(path) in str(error.value) and where in str(error.value)


def test_malformed_amc_and_missing_file(tmp_path):
    path = tmp_path / "bad.amc"
    path.write_text(TINY_AMC.replace("a 90 0 0", "a 90 x 0"))
    with pytest.raises(InputError, match="line 6"):
        read_amc(path)
    path.write_text(TINY_AMC.replace("\n2\n", "\n3\n"))
    with pytest.raises(InputError, match="frame 3 follows frame 1"):
        read_amc(path)
    with pytest.raises(InputError, match="file not found"):
        read_asf(tmp_path / "absent.asf")


def test_unknown_bone_in_a_motion(tiny, tmp_path):
    skeleton, _ = tiny
    path = tmp_path / "extra.amc"
    path.write_text(TINY_AMC + "3\nroot 0 0 0 0 0 0\nd 1 2 3\n")
    with pytest.raises(InputError, match="bones not in the skeleton: d"):
        forward_kinematics(skeleton, read_amc(path))


def test_wrong_number_of_values_is_an_input_error(tiny, tmp_path):
    skeleton, _ = tiny
    path = tmp_path / "short.amc"
    path.write_text(TINY_AMC.replace("c 90 90", "c 90"))
    with pytest.raises(InputError, match="bone c"):
        forward_kinematics(skeleton, read_amc(path))


# --- real CMU data ---------------------------------------------------------------------------

def _real(subject: str, motion: str):
    if not CMU.is_dir():
        pytest.skip(f"the real mocap data ({CMU}) is not in this checkout")
    skeleton = read_asf(CMU / subject / f"{subject}.asf")
    return skeleton, forward_kinematics(skeleton, read_amc(CMU / subject / f"{motion}.amc"))


def test_real_bone_lengths_are_constant_and_plausible():
    skeleton, (positions, rotations) = _real("02", "02_03")
    starts = positions[:, skeleton.parents[1:]]
    lengths = np.linalg.norm(positions[:, 1:] - starts, axis=-1)          # (F, B-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(skeleton.lengths[1:], lengths.shape), atol=1e-9)
    for femur in ("lfemur", "rfemur"):
        assert 0.35 < skeleton.lengths[skeleton.index(femur)] < 0.55
    coco = asf_to_coco17(positions, rotations, skeleton)
    assert coco.shape == (len(positions), 17, 3) and np.isfinite(coco).all()
    ratio = bone_lengths(coco) / MEAN_BONE_LENGTHS_M
    assert np.all((ratio > 0.6) & (ratio < 1.4)), ratio.min(axis=0)
    # a walking person stays upright: head (y up) above the hips, ankles lowest
    assert np.all(coco[:, INDEX["nose"], 1] > coco[:, INDEX["left_hip"], 1] + 0.5)
    assert np.all(coco[:, [15, 16], 1].min(axis=1) < coco[:, :15, 1].min(axis=1))


def test_real_face_points_are_rigid_and_in_front():
    skeleton, (positions, rotations) = _real("02", "02_01")
    coco = asf_to_coco17(positions, rotations, skeleton)
    distance = lambda a, b: np.linalg.norm(coco[:, INDEX[a]] - coco[:, INDEX[b]], axis=-1)  # noqa: E731
    np.testing.assert_allclose(distance("left_ear", "right_ear"), 0.150, atol=1e-9)
    np.testing.assert_allclose(distance("left_eye", "right_eye"), 0.064, atol=1e-9)
    np.testing.assert_allclose(distance("nose", "left_eye"), distance("nose", "right_eye"), atol=1e-9)
    # the nose points the way the body faces while walking: forward = (left hip - right hip) × up
    hip_axis = coco[:, INDEX["left_hip"]] - coco[:, INDEX["right_hip"]]
    forward = np.cross(hip_axis, [0.0, 1.0, 0.0])
    ears = 0.5 * (coco[:, INDEX["left_ear"]] + coco[:, INDEX["right_ear"]])
    assert np.all(np.sum((coco[:, INDEX["nose"]] - ears) * forward, axis=-1) > 0)
    # left ear on the body's left
    assert np.all(np.sum((coco[:, INDEX["left_ear"]] - coco[:, INDEX["right_ear"]]) * hip_axis, axis=-1) > 0)


# --- Panoptic --------------------------------------------------------------------------------

def _panoptic_file(path: Path, bodies) -> Path:
    path.write_text(json.dumps({"version": 0.7, "bodies": bodies}))
    return path


def test_panoptic_reader_converts_and_maps(tmp_path):
    # joint k of joints19 at (k, 100 + k, -k) cm, confidence 0.5; joint 8 (left ankle) not reconstructed
    joints = []
    for k in range(19):
        joints += [k, 100 + k, -k, -1 if k == 8 else 0.5]
    poses = read_panoptic_coco19(_panoptic_file(tmp_path / "b.json", [{"id": 7, "joints19": joints}]))
    assert poses.shape == (1, 17, 3)
    coco_from_panoptic = {"nose": 1, "left_eye": 15, "right_eye": 17, "left_ear": 16, "right_ear": 18,
                          "left_shoulder": 3, "right_shoulder": 9, "left_elbow": 4, "right_elbow": 10,
                          "left_wrist": 5, "right_wrist": 11, "left_hip": 6, "right_hip": 12,
                          "left_knee": 7, "right_knee": 13, "right_ankle": 14}
    for name, k in coco_from_panoptic.items():
        np.testing.assert_allclose(poses[0, INDEX[name]], [k / 100, 1 + k / 100, -k / 100])
    assert np.isnan(poses[0, INDEX["left_ankle"]]).all()
    assert read_panoptic_ids(tmp_path / "b.json") == [7]


def test_panoptic_reader_errors(tmp_path):
    with pytest.raises(InputError, match=r"bodies\[0\].joints19: expected 76 numbers"):
        read_panoptic_coco19(_panoptic_file(tmp_path / "short.json", [{"id": 0, "joints19": [1, 2, 3]}]))
    with pytest.raises(InputError, match="bodies"):
        read_panoptic_coco19(_panoptic_file(tmp_path / "none.json", None))
    (tmp_path / "broken.json").write_text("{")
    with pytest.raises(InputError, match="not valid JSON"):
        read_panoptic_coco19(tmp_path / "broken.json")


def test_panoptic_real_values():
    path = PANOPTIC / "body3DScene_00000168.json"
    if not path.is_file():
        pytest.skip(f"the real Panoptic data ({path}) is not in this checkout")
    poses = read_panoptic_coco19(path)
    assert poses.shape == (3, 17, 3)
    # body 0: nose (104.413, -117.401, -25.8053) cm; its left ankle has confidence -1
    np.testing.assert_allclose(poses[0, INDEX["nose"]], [1.04413, -1.17401, -0.258053])
    np.testing.assert_allclose(poses[0, INDEX["right_ankle"]], [0.698839, -0.0969057, 0.0289286])
    assert np.isnan(poses[0, INDEX["left_ankle"]]).all()
    assert read_panoptic_ids(path) == [0, 1, 2]
