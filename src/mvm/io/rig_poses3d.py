"""A rig's ``poses3d.jsonl`` (format ``mvm.rig.poses3d/1``), written and read: one JSON object
per line and instant, ``{"format", "frame", "persons": [{"id", "keypoints3d", "flags", "members",
"views_per_joint", "reprojection_error_px"}]}``.

The persons of all instants are one flat list (``instant`` says when), as arrays
(:class:`RigPoses3D`), both ways. Any problem reading is one :class:`~mvm.errors.InputError`
naming the file, the line and the field.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import orjson

from mvm.core.completion import FLAG_NAMES, MISSING, OBSERVED, flag_names
from mvm.core.keypoints import NUM_JOINTS
from mvm.errors import InputError
from mvm.io.checks import decode_text, integer, number, parse_json, read_bytes
from mvm.io.scene_dir import MAX_COORDINATE

RIG_POSES3D_FORMAT = "mvm.rig.poses3d/1"
#: The largest ``poses3d.jsonl`` read (a long capture of many people). [bytes]
MAX_RIG_POSES3D_BYTES = 2**32


@dataclass
class RigPoses3D:
    """The persons of every instant of a rig's reconstruction.

    Attributes:
        frames: ``(T,)`` frame numbers of the instants (the reference camera's), increasing.
        instant: ``(Q,)`` index into ``frames`` of each person; track: ``(Q,)`` its track id.
        X: ``(Q, 17, 3)`` joints (NaN: not reconstructed); scores: ``(Q, 17)``.
        flags: ``(Q, 17)`` int8 (:mod:`mvm.core.completion`).
        members: ``(Q, V)`` each camera's pose index within its frame (-1: none), ``V`` the
            ``cameras`` named in the members, in order of first appearance.
        views: ``(Q, 17)`` inlier 2D keypoints of each observed joint.
        reprojection_error_px: ``(Q,)`` (NaN: none).
    """

    frames: np.ndarray
    instant: np.ndarray
    track: np.ndarray
    X: np.ndarray
    scores: np.ndarray
    flags: np.ndarray
    members: np.ndarray
    cameras: list[str]
    views: np.ndarray
    reprojection_error_px: np.ndarray

    def __len__(self) -> int:
        return len(self.X)


def rig_poses3d_lines(poses: RigPoses3D, instants: range | None = None) -> bytes:
    """The lines of ``poses3d.jsonl`` for ``poses`` (its persons in the order of their instants)
    at ``instants`` (None: all of them), UTF-8: per person its ``[x, y, z, score]`` per joint
    rounded to 6 and 4 decimals (``[null, null, null, 0]`` where missing), its flags' names,
    its ``members`` as ``{camera: pose index}`` (those not -1), ``views_per_joint`` and
    ``reprojection_error_px`` (4 decimals). A long capture is written in runs of instants, in
    parallel (the rig's driver), each run's lines by one call."""
    instants = range(len(poses.frames)) if instants is None else instants
    bounds = np.searchsorted(poses.instant, np.arange(instants.start, instants.stop + 1))
    rows = slice(bounds[0], bounds[-1])
    X = np.asarray(poses.X[rows], dtype=float)
    J = NUM_JOINTS
    # [x, y, z, score] rounded; [NaN, NaN, NaN, 0] where missing (orjson writes NaN as null).
    keypoints = np.concatenate([np.round(X[:, :J], 6),
                                np.round(np.asarray(poses.scores[rows], dtype=float)[:, :J, None], 4)], axis=-1)
    keypoints[~np.isfinite(X[:, :J]).all(-1)] = (np.nan, np.nan, np.nan, 0.0)
    keypoints, names = keypoints.tolist(), flag_names(np.asarray(poses.flags[rows]))
    members, views = poses.members[rows].tolist(), np.asarray(poses.views[rows]).tolist()
    errors = np.round(np.asarray(poses.reprojection_error_px[rows], dtype=float), 4).tolist()
    ids = np.asarray(poses.track[rows]).tolist()
    out = []
    for k, t in enumerate(instants):
        found = [{"id": ids[q], "keypoints3d": keypoints[q], "flags": names[q],
                  "members": {poses.cameras[v]: m for v, m in enumerate(members[q]) if m >= 0},
                  "views_per_joint": views[q], "reprojection_error_px": errors[q]}
                 for q in range(bounds[k] - bounds[0], bounds[k + 1] - bounds[0])]
        out.append(orjson.dumps({"format": RIG_POSES3D_FORMAT, "frame": int(poses.frames[t]), "persons": found}))
    return b"\n".join(out) + b"\n" if out else b""


def _person(person, where: str, path: Path, cameras: dict[str, int]) -> tuple:
    """One person's values, checked: ``(id, keypoints (17, 4) with NaN, flags (17,), members
    {camera index: pose index}, views (17,), error)``."""
    if not isinstance(person, dict):
        raise InputError(path, where, "expected an object")
    track = integer(person.get("id"), path, f"{where}.id")
    try:
        kp = np.array(person.get("keypoints3d"), dtype=float)
    except (TypeError, ValueError, OverflowError):
        kp = np.zeros(0)
    if kp.shape != (NUM_JOINTS, 4):
        raise InputError(path, f"{where}.keypoints3d", f"expected {NUM_JOINTS} [x, y, z, score]")
    finite = np.isfinite(kp[:, :3])
    if (finite.any(1) != finite.all(1)).any() or not np.isfinite(kp[:, 3]).all():
        raise InputError(path, f"{where}.keypoints3d", "x, y and z must all be numbers or all null, score a number")
    if (np.abs(kp[:, :3][finite]) > MAX_COORDINATE).any():
        raise InputError(path, f"{where}.keypoints3d", f"coordinate beyond ±{MAX_COORDINATE:g} units")
    names = person.get("flags")
    lookup = {n: i for i, n in enumerate(FLAG_NAMES)}
    if names is None:
        flags = np.where(finite.all(1), OBSERVED, MISSING)
    elif not isinstance(names, list) or len(names) != NUM_JOINTS \
            or not all(isinstance(n, str) and n in lookup for n in names):
        raise InputError(path, f"{where}.flags", f"expected {NUM_JOINTS} names of {', '.join(FLAG_NAMES)}")
    else:
        flags = np.array([lookup[n] for n in names])
        if ((flags == MISSING) == finite.all(1)).any():
            raise InputError(path, f"{where}.flags", "'missing' must go with null coordinates, and only with them")
    members = person.get("members", {})
    if not isinstance(members, dict) or not all(integer(m, path, f"{where}.members") >= 0 for m in members.values()):
        raise InputError(path, f"{where}.members", "expected an object {camera: pose index >= 0}")
    views = person.get("views_per_joint", [0] * NUM_JOINTS)
    if not isinstance(views, list) or len(views) != NUM_JOINTS:
        raise InputError(path, f"{where}.views_per_joint", f"expected {NUM_JOINTS} integers")
    if not all(integer(v, path, f"{where}.views_per_joint") >= 0 for v in views):
        raise InputError(path, f"{where}.views_per_joint", "expected counts >= 0")
    error = person.get("reprojection_error_px")
    if error is not None:
        error = number(error, path, f"{where}.reprojection_error_px")
    local = {cameras.setdefault(str(c), len(cameras)): m for c, m in members.items()}
    return track, kp, flags, local, views, np.nan if error is None else error


def read_rig_poses3d(path: str | Path) -> RigPoses3D:
    """Read and check a rig's ``poses3d.jsonl`` (see the module)."""
    path = Path(path)
    text = decode_text(read_bytes(path, limit=MAX_RIG_POSES3D_BYTES), path)
    frames, rows, cameras = [], [], {}
    for line_number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        here = f"line {line_number}"
        record = parse_json(line, f"{path}: {here}")
        if not isinstance(record, dict) or record.get("format") != RIG_POSES3D_FORMAT:
            raise InputError(path, here, f"expected an object of format {RIG_POSES3D_FORMAT!r}")
        frame, persons = record.get("frame"), record.get("persons")
        frame = integer(frame, path, f"{here}: frame")
        if frames and frame <= frames[-1]:
            raise InputError(path, f"{here}: frame", f"frame {frame} after frame {frames[-1]}: expected increasing")
        if not isinstance(persons, list):
            raise InputError(path, f"{here}: persons", "missing, or not a list")
        rows += [(len(frames), *_person(p, f"{here}: persons[{k}]", path, cameras)) for k, p in enumerate(persons)]
        frames.append(frame)
    if not frames:
        raise InputError(path, None, "no instant: an empty reconstruction")
    Q, V = len(rows), len(cameras)
    members = np.full((Q, V), -1, dtype=np.int64)
    for q, row in enumerate(rows):
        for v, m in row[4].items():
            members[q, v] = m
    kp = np.array([r[2] for r in rows], dtype=float).reshape(Q, NUM_JOINTS, 4)
    return RigPoses3D(np.array(frames, dtype=np.int64), np.array([r[0] for r in rows], dtype=np.int64),
                      np.array([r[1] for r in rows], dtype=np.int64), kp[..., :3], kp[..., 3],
                      np.array([r[3] for r in rows], dtype=np.int8).reshape(Q, NUM_JOINTS), members,
                      list(cameras), np.array([r[5] for r in rows], dtype=np.int64).reshape(Q, NUM_JOINTS),
                      np.array([r[6] for r in rows], dtype=float))
