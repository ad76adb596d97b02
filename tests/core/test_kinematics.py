"""Kinematics of motion-capture skeletons: Euler matrices against SciPy, forward kinematics of a
skeleton built by hand."""
import numpy as np
import pytest

from mvm.core.kinematics import Skeleton, euler_matrices, forward_kinematics, rest_frame


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


def _chain() -> Skeleton:
    """A root and two bones: ``up`` (1 m along +y), then ``out`` (0.5 m along +x); axes aligned."""
    eye = np.broadcast_to(np.eye(3), (3, 3, 3)).copy()
    return Skeleton(names=("root", "up", "out"), parents=np.array([-1, 0, 1]),
                    directions=np.array([[0.0, 0, 0], [0, 1, 0], [1, 0, 0]]), lengths=np.array([0.0, 1.0, 0.5]),
                    axes=eye, axis_orders=("XYZ",) * 3, dofs=(("rx", "ry", "rz"),) * 3,
                    limits=(np.zeros((0, 2)),) * 3, root_position=np.array([1.0, 2.0, 3.0]),
                    length_to_m=1.0, angle_to_rad=1.0)


def test_forward_kinematics_of_a_chain_by_hand():
    skeleton = _chain()
    angles = np.zeros((2, 3, 3))
    angles[1, 0, 2] = np.pi / 2                    # frame 1: the root turned 90° about z
    angles[1, 1, 0] = np.pi / 2                    # and ``up`` 90° about x
    positions, rotations = forward_kinematics(skeleton, np.array([[1.0, 2, 3], [0, 0, 0]]), angles)
    np.testing.assert_allclose(positions[0], [[1, 2, 3], [1, 3, 3], [1.5, 3, 3]], atol=1e-12)
    # Rz(90) Rx(90) (0, 1, 0) = Rz(90) (0, 0, 1) = (0, 0, 1); then Rz(90) Rx(90) (0.5, 0, 0) = (0, 0.5, 0)
    np.testing.assert_allclose(positions[1], [[0, 0, 0], [0, 0, 1], [0, 0.5, 1]], atol=1e-12)
    np.testing.assert_allclose(rotations[0], np.broadcast_to(np.eye(3), (3, 3, 3)), atol=1e-12)
    with pytest.raises(ValueError, match="expected angles"):
        forward_kinematics(skeleton, np.zeros((2, 3)), np.zeros((2, 2, 3)))


def test_rest_frame_by_hand():
    # left: from the start of ``up`` (the root) to the start of ``out`` (1 m up): +y; up: root to
    # the end of ``out`` (0.5, 1, 0), less its +y part: +x; forward = left × up = -z.
    frame = rest_frame(_chain(), left="out", right="up", top="out")
    np.testing.assert_allclose(frame, [[0, 1, 0], [1, 0, 0], [0, 0, -1]], atol=1e-12)
