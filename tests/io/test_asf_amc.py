"""ASF/AMC readers: hand-computed forward kinematics of a parsed skeleton, real-data sanity, clear errors."""
from __future__ import annotations

import numpy as np
import pytest

from mvm.core.keypoints import INDEX, MEAN_BONE_LENGTHS_M, bone_lengths
from mvm.core.kinematics import asf_to_coco17, forward_kinematics
from mvm.errors import InputError
from mvm.io.asf_amc import INCH_M, motion_arrays, read_amc, read_asf, read_motion

from helpers import SHARED_DATA  # noqa: E402

CMU = SHARED_DATA / "cmu_mocap"

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
    positions, rotations = forward_kinematics(skeleton, *motion_arrays(skeleton, frames))
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
    np.testing.assert_allclose(rotations[0] @ np.swapaxes(rotations[0], -1, -2), np.broadcast_to(np.eye(3), (4, 3, 3)),
                               atol=1e-12)


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
    with pytest.raises(InputError, match="bones not in the skeleton: d") as error:
        read_motion(path, skeleton)
    assert str(path) in str(error.value)


def test_wrong_number_of_values_is_an_input_error(tiny, tmp_path):
    skeleton, _ = tiny
    path = tmp_path / "short.amc"
    path.write_text(TINY_AMC.replace("c 90 90", "c 90"))
    with pytest.raises(InputError, match="bone c"):
        read_motion(path, skeleton)


# --- real CMU data ---------------------------------------------------------------------------

def _real(subject: str, motion: str):
    if not CMU.is_dir():
        pytest.skip(f"the real mocap data ({CMU}) is not in this checkout")
    skeleton = read_asf(CMU / subject / f"{subject}.asf")
    return skeleton, forward_kinematics(skeleton, *read_motion(CMU / subject / f"{motion}.amc", skeleton))


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
