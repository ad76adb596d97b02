"""Acclaim motion capture: ASF skeletons and AMC motions (the CMU motion-capture database).

The readers return a :class:`mvm.core.kinematics.Skeleton` and the arrays that
:func:`mvm.core.kinematics.forward_kinematics` turns into joint positions (the convention is
described there).

Lengths are converted to metres with ``0.0254 / length_unit``: the ``:units length`` field of the
CMU files (0.45) is the number of file units per inch (the CMU femur, 7.16 units, is 0.40 m).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mvm.core.kinematics import Skeleton, euler_matrices
from mvm.errors import InputError
from mvm.io.checks import read_text

#: Metres per inch; an ASF length of ``v`` file units is ``v * INCH_M / length_unit`` metres.
INCH_M = 0.0254

_ROTATION_DOFS = ("rx", "ry", "rz")
_KNOWN_DOFS = ("tx", "ty", "tz", "rx", "ry", "rz", "l")


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
                raise InputError(path, f"line {line}",
                                 f"bad dof list {' '.join(values)!r} (known: {' '.join(_KNOWN_DOFS)})")
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


def motion_arrays(skeleton: Skeleton, frames: list[dict[str, tuple[float, ...]]], path: str | Path | None = None
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
            raise InputError(path, f"bone {name}", f"expected {len(dofs)} values per frame ({' '.join(dofs)})")
        values = np.array([r for r in rows if r is not None], dtype=float)
        for k, dof in enumerate(dofs):
            if dof in _ROTATION_DOFS:
                angles[present, b, _ROTATION_DOFS.index(dof)] = values[:, k] * skeleton.angle_to_rad
            elif dof in ("tx", "ty", "tz") and b == 0:
                root_positions[present, "xyz".index(dof[1])] = values[:, k] * skeleton.length_to_m
    unknown = set().union(*frames) - names
    if unknown:
        raise InputError(path, "motion", f"bones not in the skeleton: {', '.join(sorted(unknown))}")
    return root_positions, angles


def read_motion(path: str | Path, skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Read an AMC motion of ``skeleton``: ``root_positions: (F, 3)`` metres and ``angles: (F, B, 3)``
    radians, the input of :func:`mvm.core.kinematics.forward_kinematics`."""
    return motion_arrays(skeleton, read_amc(path), path)
