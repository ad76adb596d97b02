"""Motion-capture readers: Acclaim ASF/AMC skeletons and motions, and CMU Panoptic 3D bodies.

The Acclaim convention (as in the CMU motion-capture database):

* every bone has a ``direction`` (unit vector, global rest frame), a ``length``, and an ``axis``
  line giving three Euler angles and their order; ``C`` is the rotation those angles build;
* a frame gives each bone's rotation ``M`` about its own axes: the angles of its ``dof`` (listed
  in any order), composed in the order of the ``axis`` line (``XYZ``: ``M = Rz · Ry · Rx``);
* the global rotation of a bone is ``R = R_parent · C · M · C⁻¹`` and its end point is
  ``p = p_parent + length · R · direction`` (``p_parent`` is the parent's end point, the root's
  parent point is the root position of the frame).

Lengths are converted to metres with ``0.0254 / length_unit``: the ``:units length`` field of the
CMU files (0.45) is the number of file units per inch (the CMU femur, 7.16 units, is 0.40 m).

Everything here returns arrays; no function keeps state between calls.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.core.keypoints import COCO_KEYPOINTS, INDEX, NUM_JOINTS
from mvm.errors import InputError
from mvm.io.checks import load_json, read_text

#: Metres per inch; an ASF length of ``v`` file units is ``v * INCH_M / length_unit`` metres.
INCH_M = 0.0254

_ROTATION_DOFS = ("rx", "ry", "rz")
_KNOWN_DOFS = ("tx", "ty", "tz", "rx", "ry", "rz", "l")

# --- anthropometric face offsets (metres) in the head frame (left, up, forward) ------------
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

#: Panoptic ``joints19`` order (the data set's documentation).
PANOPTIC_JOINTS19: tuple[str, ...] = (
    "neck", "nose", "body_centre", "left_shoulder", "left_elbow", "left_wrist", "left_hip",
    "left_knee", "left_ankle", "right_shoulder", "right_elbow", "right_wrist", "right_hip",
    "right_knee", "right_ankle", "left_eye", "left_ear", "right_eye", "right_ear",
)
#: For each COCO keypoint, its index in ``PANOPTIC_JOINTS19``.
PANOPTIC_TO_COCO17 = np.array([PANOPTIC_JOINTS19.index(name) for name in COCO_KEYPOINTS])


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


# --- ASF ------------------------------------------------------------------------------------

def _sections(lines: list[str]) -> dict[str, list[tuple[int, str]]]:
    """Split an ASF into its ``:keyword`` sections: name -> [(line number, text)]."""
    sections: dict[str, list[tuple[int, str]]] = {}
    current = None
    for number, raw in enumerate(lines, start=1):
        text = raw.split("#", 1)[0].strip()
        if not text:
            continue
        if text.startswith(":"):
            keyword, _, rest = text[1:].partition(" ")
            current = sections.setdefault(keyword.lower(), [])
            if rest.strip():
                current.append((number, rest.strip()))
        elif current is not None:
            current.append((number, text))
    return sections


def _floats(tokens: list[str], path, line: int, count: int | None = None) -> list[float]:
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        raise InputError(path, f"line {line}", f"expected numbers, got {' '.join(tokens)!r}") from None
    if count is not None and len(values) != count:
        raise InputError(path, f"line {line}", f"expected {count} numbers, got {len(values)}")
    if not all(math.isfinite(v) for v in values):
        raise InputError(path, f"line {line}", "not a finite number")
    return values


def _units(entries, path) -> tuple[float, float]:
    length_unit, angle_to_rad = 1.0, math.pi / 180.0
    for line, text in entries:
        key, *values = text.split()
        if key == "length":
            (length_unit,) = _floats(values, path, line, 1)
            if length_unit <= 0:
                raise InputError(path, f"line {line}", f"length unit must be positive, got {length_unit}")
        elif key == "angle":
            if values not in (["deg"], ["rad"]):
                raise InputError(path, f"line {line}", f"angle unit must be 'deg' or 'rad', got {' '.join(values)!r}")
            angle_to_rad = math.pi / 180.0 if values == ["deg"] else 1.0
        elif key != "mass":
            raise InputError(path, f"line {line}", f"unknown unit {key!r} (expected mass, length, angle)")
    return INCH_M / length_unit, angle_to_rad


def _order(token: str, path, line: int) -> str:
    order = token.upper()
    if sorted(order) != ["X", "Y", "Z"]:
        raise InputError(path, f"line {line}", f"expected an Euler order such as XYZ, got {token!r}")
    return order


def _root(entries, path, length_to_m, angle_to_rad) -> dict:
    root = {"order": ("tx", "ty", "tz", "rx", "ry", "rz"), "axis": "XYZ",
            "position": np.zeros(3), "orientation": np.zeros(3)}
    for line, text in entries:
        key, *values = text.split()
        if key == "order":
            dofs = tuple(v.lower() for v in values)
            if not dofs or any(d not in _KNOWN_DOFS[:6] for d in dofs) or len(set(dofs)) != len(dofs):
                raise InputError(path, f"line {line}", f"bad root order {' '.join(values)!r}")
            root["order"] = dofs
        elif key == "axis":
            if len(values) != 1:
                raise InputError(path, f"line {line}", "root axis: expected one Euler order such as XYZ")
            root["axis"] = _order(values[0], path, line)
        elif key == "position":
            root["position"] = np.array(_floats(values, path, line, 3)) * length_to_m
        elif key == "orientation":
            root["orientation"] = np.array(_floats(values, path, line, 3)) * angle_to_rad
        else:
            raise InputError(path, f"line {line}", f"unknown root field {key!r}")
    return root


def _bones(entries, path) -> list[dict]:
    """Parse ``:bonedata`` into dicts with the raw (unconverted) fields."""
    bones: list[dict] = []
    bone = None
    limits_pending = 0
    for line, text in entries:
        key, *values = text.split()
        if limits_pending and key.startswith("("):
            bone["limits"].append(_limit(text, path, line))
            limits_pending -= 1
            continue
        if key == "begin":
            bone = {"line": line, "dof": (), "limits": [], "axis": None}
            limits_pending = 0
        elif bone is None:
            raise InputError(path, f"line {line}", f"{key!r} outside a begin ... end block")
        elif key == "end":
            _check_bone(bone, path)
            bones.append(bone)
            bone = None
        elif key == "id":
            bone["id"] = values
        elif key == "name":
            if len(values) != 1:
                raise InputError(path, f"line {line}", "a bone name is one word")
            bone["name"] = values[0]
        elif key == "direction":
            bone["direction"] = _floats(values, path, line, 3)
        elif key == "length":
            (bone["length"],) = _floats(values, path, line, 1)
        elif key == "axis":
            if len(values) != 4:
                raise InputError(path, f"line {line}", "axis: expected three angles and an order such as XYZ")
            bone["axis"] = (_floats(values[:3], path, line, 3), _order(values[3], path, line))
        elif key == "dof":
            dofs = tuple(v.lower() for v in values)
            if any(d not in _KNOWN_DOFS for d in dofs) or len(set(dofs)) != len(dofs):
                raise InputError(path, f"line {line}", f"bad dof list {' '.join(values)!r} (known: {' '.join(_KNOWN_DOFS)})")
            bone["dof"] = dofs
        elif key == "limits":
            bone["limits"].append(_limit(" ".join(values), path, line))
            limits_pending = len(bone["dof"]) - 1
        elif key in ("bodymass", "cofmass"):
            continue
        else:
            raise InputError(path, f"line {line}", f"unknown bone field {key!r}")
    if bone is not None:
        raise InputError(path, f"line {bone['line']}", "bone block without 'end'")
    return bones


def _limit(text: str, path, line: int) -> tuple[float, float]:
    """``"(-160.0 20.0)"`` -> (-160.0, 20.0); ``inf`` is allowed."""
    tokens = text.replace("(", " ").replace(")", " ").split()
    try:
        low, high = (float(t) for t in tokens)
    except ValueError:
        raise InputError(path, f"line {line}", f"limits: expected '(min max)', got {text!r}") from None
    return low, high


def _check_bone(bone: dict, path) -> None:
    where = f"line {bone['line']}"
    for key in ("name", "direction", "length", "axis"):
        if key not in bone or bone[key] is None:
            raise InputError(path, where, f"bone block without '{key}'")
    if bone["limits"] and len(bone["limits"]) != len(bone["dof"]):
        raise InputError(path, where, f"bone {bone['name']}: {len(bone['dof'])} dofs but {len(bone['limits'])} limits")
    norm = np.linalg.norm(bone["direction"])
    if not norm > 0:
        raise InputError(path, where, f"bone {bone['name']}: zero direction")
    bone["direction"] = np.asarray(bone["direction"]) / norm


def _hierarchy(entries, path, names: list[str]) -> dict[str, str]:
    """``:hierarchy`` -> child name: parent name."""
    parent_of: dict[str, str] = {}
    for line, text in entries:
        tokens = text.split()
        if tokens in (["begin"], ["end"]):
            continue
        parent, *children = tokens
        for name in [parent, *children]:
            if name != "root" and name not in names:
                raise InputError(path, f"line {line}", f"unknown bone {name!r} in the hierarchy")
        for child in children:
            if child in parent_of:
                raise InputError(path, f"line {line}", f"bone {child!r} has two parents")
            parent_of[child] = parent
    return parent_of


def _topological(names: list[str], parent_of: dict[str, str], path) -> list[str]:
    """Bone names ordered so that every parent precedes its children, starting at 'root'."""
    ordered = ["root"]
    children: dict[str, list[str]] = {}
    for child, parent in parent_of.items():
        children.setdefault(parent, []).append(child)
    i = 0
    while i < len(ordered):
        ordered.extend(children.get(ordered[i], []))
        i += 1
    unreachable = [n for n in names if n not in ordered]
    if unreachable:
        raise InputError(path, ":hierarchy", f"bones not connected to the root: {', '.join(unreachable)}")
    return ordered


def read_asf(path: str | Path) -> Skeleton:
    """Read an Acclaim skeleton file; any malformed line raises one ``InputError``."""
    path = Path(path)
    lines = _read_lines(path)
    sections = _sections(lines)
    for required in ("bonedata", "hierarchy"):
        if required not in sections:
            raise InputError(path, f":{required}", "section missing")
    length_to_m, angle_to_rad = _units(sections.get("units", []), path)
    root = _root(sections.get("root", []), path, length_to_m, angle_to_rad)
    bones = {b["name"]: b for b in _bones(sections["bonedata"], path)}
    parent_of = _hierarchy(sections["hierarchy"], path, list(bones))
    ordered = _topological(list(bones), parent_of, path)
    position = {name: i for i, name in enumerate(ordered)}
    root_bone = {"direction": np.zeros(3), "length": 0.0, "dof": root["order"], "limits": [],
                 "axis": (root["orientation"] / angle_to_rad, root["axis"])}
    table = [root_bone] + [bones[n] for n in ordered[1:]]
    return Skeleton(
        names=tuple(ordered),
        parents=np.array([-1] + [position[parent_of[n]] for n in ordered[1:]]),
        directions=np.array([b["direction"] for b in table], dtype=float),
        lengths=np.array([b["length"] for b in table], dtype=float) * length_to_m,
        axes=np.stack([euler_matrices(np.asarray(b["axis"][0]) * angle_to_rad, b["axis"][1]) for b in table]),
        axis_orders=tuple(b["axis"][1] for b in table),
        dofs=tuple(tuple(b["dof"]) for b in table),
        limits=tuple(np.array(b["limits"], dtype=float).reshape(-1, 2) for b in table),
        root_position=np.asarray(root["position"], dtype=float),
        length_to_m=length_to_m,
        angle_to_rad=angle_to_rad,
    )


def _read_lines(path: Path) -> list[str]:
    return read_text(path).splitlines()


# --- AMC ------------------------------------------------------------------------------------

def read_amc(path: str | Path) -> list[dict[str, tuple[float, ...]]]:
    """Read an Acclaim motion: one dict per frame, bone name -> its values in file units.

    Frames must be numbered 1, 2, 3, ... in order; header lines (``:FULLY-SPECIFIED``,
    ``:DEGREES``) and comments are skipped.
    """
    path = Path(path)
    frames: list[dict[str, tuple[float, ...]]] = []
    frame = None
    for number, raw in enumerate(_read_lines(path), start=1):
        text = raw.strip()
        if not text or text.startswith(("#", ":")):
            continue
        tokens = text.split()
        if len(tokens) == 1:
            if not tokens[0].isdigit():
                raise InputError(path, f"line {number}", f"expected a frame number, got {tokens[0]!r}")
            if int(tokens[0]) != len(frames) + 1:
                raise InputError(path, f"line {number}", f"frame {tokens[0]} follows frame {len(frames)}")
            frame = {}
            frames.append(frame)
        elif frame is None:
            raise InputError(path, f"line {number}", "bone values before the first frame number")
        else:
            try:
                frame[tokens[0]] = tuple(map(float, tokens[1:]))
            except ValueError:
                raise InputError(path, f"line {number}", f"expected numbers after {tokens[0]!r}") from None
    if not frames:
        raise InputError(path, None, "no frames")
    return frames


def motion_arrays(skeleton: Skeleton, frames: list[dict[str, tuple[float, ...]]]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """AMC frames -> ``(root_positions: (F, 3) metres, angles: (F, B, 3) radians about x, y, z)``.

    A bone absent from a frame, or without rotation dofs, keeps angle 0 (its rest pose).
    """
    names = set(skeleton.names)
    f_count = len(frames)
    angles = np.zeros((f_count, len(skeleton.names), 3))
    root_positions = np.broadcast_to(skeleton.root_position, (f_count, 3)).copy()
    for b, (name, dofs) in enumerate(zip(skeleton.names, skeleton.dofs)):
        if not dofs:
            continue
        rows = [frame.get(name) for frame in frames]
        present = np.array([r is not None for r in rows])
        if not present.any():
            continue
        lengths = {len(r) for r in rows if r is not None}
        if lengths != {len(dofs)}:
            raise InputError(None, f"bone {name}", f"expected {len(dofs)} values per frame ({' '.join(dofs)})")
        values = np.array([r for r in rows if r is not None], dtype=float)
        for k, dof in enumerate(dofs):
            if dof in _ROTATION_DOFS:
                angles[present, b, _ROTATION_DOFS.index(dof)] = values[:, k] * skeleton.angle_to_rad
            elif dof in ("tx", "ty", "tz") and b == 0:
                root_positions[present, "xyz".index(dof[1])] = values[:, k] * skeleton.length_to_m
    unknown = set().union(*frames) - names
    if unknown:
        raise InputError(None, "motion", f"bones not in the skeleton: {', '.join(sorted(unknown))}")
    return root_positions, angles


def forward_kinematics(skeleton: Skeleton, frames) -> tuple[np.ndarray, np.ndarray]:
    """Bone end points and global rotations of every frame.

    ``frames``: the list ``read_amc`` returns, or ``(root_positions: (F, 3), angles: (F, B, 3))``
    from ``motion_arrays``. Returns ``positions: (F, B, 3)`` metres (the end point of each bone;
    the root's is the root position) and ``rotations: (F, B, 3, 3)`` (global, rest frame -> world).
    """
    root_positions, angles = frames if isinstance(frames, tuple) else motion_arrays(skeleton, frames)
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
    zero = (skeleton.root_position[None], np.zeros((1, len(skeleton.names), 3)))
    positions, _ = forward_kinematics(skeleton, zero)
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


# --- Panoptic --------------------------------------------------------------------------------

def read_panoptic_coco19(path: str | Path) -> np.ndarray:
    """One Panoptic ``body3DScene_*.json`` -> ``(bodies, 17, 3)`` metres in Panoptic's world axes (y down).

    Joints with a negative confidence (Panoptic's mark for "not reconstructed") are NaN.
    Bodies come in file order; their ids are given by ``read_panoptic_ids``.
    """
    bodies = _panoptic_bodies(Path(path))
    out = np.empty((len(bodies), NUM_JOINTS, 3))
    for i, joints in enumerate(bodies):
        xyz = joints[PANOPTIC_TO_COCO17, :3] / 100.0
        xyz[joints[PANOPTIC_TO_COCO17, 3] < 0] = np.nan
        out[i] = xyz
    return out


def read_panoptic_ids(path: str | Path) -> list[int]:
    """The ``id`` of every body of a Panoptic ``body3DScene_*.json``, in file order."""
    path = Path(path)
    data = _panoptic_json(path)
    return [_panoptic_id(body, path, i) for i, body in enumerate(data["bodies"])]


def _panoptic_json(path: Path) -> dict:
    data = load_json(path)
    if not isinstance(data, dict) or not isinstance(data.get("bodies"), list):
        raise InputError(path, "bodies", "missing, or not a list")
    return data


def _panoptic_id(body, path, i) -> int:
    if not isinstance(body, dict) or isinstance(body.get("id"), bool) or not isinstance(body.get("id"), int):
        raise InputError(path, f"bodies[{i}].id", "missing, or not an integer")
    return body["id"]


def _panoptic_bodies(path: Path) -> list[np.ndarray]:
    """``bodies[].joints19`` as ``(19, 4)`` arrays x, y, z (cm), confidence."""
    data = _panoptic_json(path)
    out = []
    for i, body in enumerate(data["bodies"]):
        field = f"bodies[{i}].joints19"
        values = body.get("joints19") if isinstance(body, dict) else None
        if not isinstance(values, list) or len(values) != 4 * len(PANOPTIC_JOINTS19):
            got = len(values) if isinstance(values, list) else type(values).__name__
            raise InputError(path, field, f"expected {4 * len(PANOPTIC_JOINTS19)} numbers (19 joints × x, y, z, confidence), got {got}")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values):
            raise InputError(path, field, "expected finite numbers")
        out.append(np.asarray(values, dtype=float).reshape(len(PANOPTIC_JOINTS19), 4))
    return out
