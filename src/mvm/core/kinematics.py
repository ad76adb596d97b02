"""Forward kinematics of motion-capture skeletons (the Acclaim ASF/AMC convention) and the COCO-17
keypoints of a CMU skeleton. Arrays in, arrays out; the files are read by :mod:`mvm.io.asf_amc`.

The Acclaim convention (as in the CMU motion-capture database):

* every bone has a ``direction`` (unit vector, global rest frame), a ``length``, and an ``axis``
  line giving three Euler angles and their order; ``C`` is the rotation those angles build;
* a frame gives each bone's rotation ``M`` about its own axes: the angles of its ``dof`` (listed
  in any order), composed in the order of the ``axis`` line (``XYZ``: ``M = Rz · Ry · Rx``);
* the global rotation of a bone is ``R = R_parent · C · M · C⁻¹`` and its end point is
  ``p = p_parent + length · R · direction`` (``p_parent`` is the parent's end point, the root's
  parent point is the root position of the frame).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mvm.core.keypoints import INDEX, NUM_JOINTS

# --- anthropometric face offsets (metres) in the head frame (left, up, forward) -----------
# Relative to the end point of the ASF ``head`` bone, which the CMU skeleton places about at
# the height of the eyes (0.30 m above the thorax end, i.e. the base of the neck, and 0.19 m
# above the shoulder joints). Adult means: interpupillary distance 64 mm, head breadth at the
# ears 150 mm, eyes 90 mm forward of the ear canals (tragion) and 15 mm above them, nose tip
# 110 mm forward of the ears and 35 mm below the eyes. The distances they give (ear-ear 0.150,
# eye-ear 0.101, nose-ear 0.135, nose-eye 0.051 m) match the medians of the real face points
# of the CMU Panoptic bodies (0.151, 0.101, 0.135, 0.050 m).
FACE_OFFSETS_M: dict[str, tuple[float, float, float]] = {
    "nose": (0.0, -0.035, 0.110),
    "left_eye": (0.032, 0.0, 0.090),
    "right_eye": (-0.032, 0.0, 0.090),
    "left_ear": (0.075, -0.015, 0.0),
    "right_ear": (-0.075, -0.015, 0.0),
}


@dataclass(frozen=True)
class Skeleton:
    """An ASF skeleton. Bone 0 is the root (length 0); every other bone's parent comes before it.

    Attributes:
        names: ``B`` bone names; parents: ``(B,)`` parent index (-1 for the root);
        directions: ``(B, 3)`` unit directions in the global rest frame; lengths: ``(B,)`` metres;
        axes: ``(B, 3, 3)`` the rotation ``C`` of each bone's ``axis`` line;
        axis_orders: ``B`` Euler orders such as ``"XYZ"`` (the order the rotations are applied);
        dofs: ``B`` tuples of dof names in the order an AMC frame lists their values;
        limits: ``B`` arrays ``(len(dofs), 2)``; root_position: ``(3,)`` metres (rest pose);
        length_to_m: metres per file length unit; angle_to_rad: radians per file angle unit.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    directions: np.ndarray
    lengths: np.ndarray
    axes: np.ndarray
    axis_orders: tuple[str, ...]
    dofs: tuple[tuple[str, ...], ...]
    limits: tuple[np.ndarray, ...]
    root_position: np.ndarray
    length_to_m: float
    angle_to_rad: float

    def index(self, name: str) -> int:
        """Index of bone ``name``; an unknown name is answered with the known ones."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no bone {name!r} in the skeleton; bones: {', '.join(self.names)}") from None


# --- rotations ------------------------------------------------------------------------------

def euler_matrices(angles: np.ndarray, order: str) -> np.ndarray:
    """Rotation matrices of Euler angles applied in ``order`` about fixed axes.

    ``angles: (..., 3)`` radians about x, y, z (whatever the order) -> ``(..., 3, 3)``.
    For ``order="XYZ"`` the result is ``Rz · Ry · Rx``: the rotation about x is applied first.

    >>> euler_matrices(np.array([0.0, 0.0, np.pi / 2]), "XYZ").round(12) @ [1.0, 0.0, 0.0]
    array([0., 1., 0.])
    >>> R = euler_matrices(np.array([0.3, -0.2, 1.1]), "ZXY")
    >>> np.allclose(R @ R.T, np.eye(3)) and bool(np.isclose(np.linalg.det(R), 1.0))
    True
    """
    angles = np.asarray(angles, dtype=float)
    out = np.broadcast_to(np.eye(3), angles.shape[:-1] + (3, 3)).copy()
    for letter in order.upper():
        axis = "XYZ".index(letter)
        out = _axis_rotation(angles[..., axis], axis) @ out
    return out


def _axis_rotation(theta: np.ndarray, axis: int) -> np.ndarray:
    """``theta: (...)`` radians about coordinate ``axis`` -> ``(..., 3, 3)``."""
    c, s = np.cos(theta), np.sin(theta)
    r = np.zeros(np.shape(theta) + (3, 3))
    i, j = (axis + 1) % 3, (axis + 2) % 3          # cyclic: (y, z) for x, (z, x) for y, (x, y) for z
    r[..., axis, axis] = 1.0
    r[..., i, i] = c
    r[..., j, j] = c
    r[..., j, i] = s
    r[..., i, j] = -s
    return r


def forward_kinematics(skeleton: Skeleton, root_positions: np.ndarray, angles: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Bone end points and global rotations of every frame.

    ``root_positions: (F, 3)`` metres and ``angles: (F, B, 3)`` radians about x, y, z (as
    :func:`mvm.io.asf_amc.read_motion` returns them) -> ``positions: (F, B, 3)`` metres (the end
    point of each bone; the root's is the root position) and ``rotations: (F, B, 3, 3)`` (global,
    rest frame -> world).
    """
    root_positions = np.asarray(root_positions, dtype=float)
    angles = np.asarray(angles, dtype=float)
    f_count, b_count = angles.shape[0], len(skeleton.names)
    if angles.shape != (f_count, b_count, 3) or root_positions.shape != (f_count, 3):
        raise ValueError(f"expected angles (F, {b_count}, 3) and root positions (F, 3), "
                         f"got {angles.shape} and {root_positions.shape}")
    positions = np.empty((f_count, b_count, 3))
    rotations = np.empty((f_count, b_count, 3, 3))
    for b in range(b_count):
        c = skeleton.axes[b]
        local = c @ euler_matrices(angles[:, b], skeleton.axis_orders[b]) @ c.T
        parent = skeleton.parents[b]
        if parent < 0:
            rotations[:, b] = local
            positions[:, b] = root_positions
            continue
        rotations[:, b] = rotations[:, parent] @ local
        offset = skeleton.lengths[b] * skeleton.directions[b]
        positions[:, b] = positions[:, parent] + rotations[:, b] @ offset
    return positions, rotations


def rest_frame(skeleton: Skeleton, left: str = "lfemur", right: str = "rfemur", top: str = "head"
               ) -> np.ndarray:
    """The skeleton's body axes in its rest pose: ``(3, 3)`` rows left, up, forward (unit vectors).

    Left runs from the right hip to the left hip; up from the root to the top of ``top``,
    orthogonalized; forward = left × up.
    """
    positions, _ = forward_kinematics(skeleton, skeleton.root_position[None], np.zeros((1, len(skeleton.names), 3)))
    p = positions[0]
    start = lambda name: p[skeleton.parents[skeleton.index(name)]]  # noqa: E731
    left_axis = _unit(start(left) - start(right))
    up = p[skeleton.index(top)] - p[0]
    up = _unit(up - np.dot(up, left_axis) * left_axis)
    return np.stack([left_axis, up, np.cross(left_axis, up)])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# --- ASF -> COCO-17 -------------------------------------------------------------------------

#: COCO body keypoint -> (bone, t): the point ``start + t · (end - start)`` of a CMU bone.
#: The CMU forearm is two segments, ``lradius`` and ``lwrist`` (the latter carries the twist);
#: the midpoint of ``lwrist`` gives forearm lengths (0.24 m) that match the adult mean (0.25 m)
#: and the CMU Panoptic bodies (0.24 m), where the end of ``lradius`` gives 0.20 m.
CMU_BODY_POINTS: dict[str, tuple[str, float]] = {
    "left_shoulder": ("lhumerus", 0.0), "right_shoulder": ("rhumerus", 0.0),
    "left_elbow": ("lhumerus", 1.0), "right_elbow": ("rhumerus", 1.0),
    "left_wrist": ("lwrist", 0.5), "right_wrist": ("rwrist", 0.5),
    "left_hip": ("lfemur", 0.0), "right_hip": ("rfemur", 0.0),
    "left_knee": ("lfemur", 1.0), "right_knee": ("rfemur", 1.0),
    "left_ankle": ("ltibia", 1.0), "right_ankle": ("rtibia", 1.0),
}
#: COCO hip keypoints lie this far lateral of the CMU hip joint centres, along the hip axis (m).
#: The CMU hip joint centres are 0.15 m apart; COCO-style hips, as annotated and as CMU
#: Panoptic reconstructs them, are 0.23 m apart.
HIP_LATERAL_OFFSET_M = 0.04


def asf_to_coco17(positions: np.ndarray, rotations: np.ndarray, skeleton: Skeleton,
                  head: str = "head") -> np.ndarray:
    """COCO-17 keypoints of ASF frames. ``positions: (F, B, 3)``, ``rotations: (F, B, 3, 3)`` -> ``(F, 17, 3)``.

    Body points lie on bones (``CMU_BODY_POINTS``), the hips moved apart by
    ``HIP_LATERAL_OFFSET_M`` each; the face points are the end of the ``head`` bone plus
    ``FACE_OFFSETS_M`` along the head's left, up and forward axes (the rest pose's body axes
    carried by the head's global rotation).
    """
    positions = np.asarray(positions, dtype=float)
    out = np.empty(positions.shape[:-2] + (NUM_JOINTS, 3))
    for name, (bone, t) in CMU_BODY_POINTS.items():
        b = skeleton.index(bone)
        start, end = positions[..., skeleton.parents[b], :], positions[..., b, :]
        out[..., INDEX[name], :] = start + t * (end - start)
    lh, rh = INDEX["left_hip"], INDEX["right_hip"]
    lateral = _unit(out[..., lh, :] - out[..., rh, :])
    out[..., lh, :] += HIP_LATERAL_OFFSET_M * lateral
    out[..., rh, :] -= HIP_LATERAL_OFFSET_M * lateral
    h = skeleton.index(head)
    axes = np.einsum("...ij,kj->...ik", rotations[..., h, :, :], rest_frame(skeleton, top=head))  # columns l, u, f
    for name, offset in FACE_OFFSETS_M.items():
        out[..., INDEX[name], :] = positions[..., h, :] + axes @ np.asarray(offset)
    return out
