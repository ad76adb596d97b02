"""The scene directory (docs/architecture.md): ``sparse/`` + ``poses2d.json`` in, ``mvm/poses3d.json`` out."""
from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from mvm.core.keypoints import COCO_KEYPOINTS, NUM_JOINTS
from mvm.core.scene import Cameras, Persons3D, Poses2D, Scene
from mvm.errors import InputError
from mvm.io.checks import integer, load_json, number, numbers
from mvm.io.coco import coco_keypoints_document, read_coco_keypoints
from mvm.io.colmap import read_colmap, undistort_keypoints, write_colmap
from mvm.io.files import atomic_replace_dir, atomic_write_json
from mvm.io.paths import resolve_in

log = logging.getLogger(__name__)

POSES2D = "poses2d.json"
FRAMES = "frames"
SPARSE = "sparse"
POSES3D_FORMAT = "mvm.poses3d/1"


def read_scene(path: str | Path) -> Scene:
    """Read a scene directory into a :class:`Scene` (keypoints undistorted, unregistered
    images' poses dropped with a warning).

    Image names (COCO ``file_name``, COLMAP ``NAME``) name files of ``frames/``: a name that is
    absolute, climbs out with ``..``, or resolves through a symbolic link to a place outside
    the scene directory is refused (:func:`mvm.io.paths.resolve_in`).
    """
    path = Path(path)
    if not path.is_dir():
        raise InputError(path, None, "not a scene directory (expected sparse/ and poses2d.json)")
    model = read_colmap(path / SPARSE)
    coco_path = path / POSES2D
    coco = read_coco_keypoints(coco_path)
    view_of_name = model.index()
    unregistered = set(model.unregistered)
    image_view = np.full(len(coco.file_names), -1)
    for i, name in enumerate(coco.file_names):
        resolve_in(path / FRAMES, name, coco_path, f"images[{i}].file_name", scene=path)
        if name in view_of_name:
            image_view[i] = view_of_name[name]
        elif name not in unregistered:
            raise InputError(coco_path, f"images[{i}].file_name",
                             f"image {name!r} is not in the COLMAP model {path / SPARSE}")
    view = image_view[coco.ann_image]
    kept = view >= 0
    if (~kept).any():
        log.warning("%s: %d 2D poses are in images without a camera pose and are ignored",
                    coco_path, int((~kept).sum()))
    if not kept.any():
        raise InputError(coco_path, "annotations", "no 2D poses in registered images: nothing to reconstruct")
    keypoints = coco.keypoints[kept].copy()
    keypoints[:, :, :2] = undistort_keypoints(model, view[kept], keypoints[:, :, :2])
    keypoints[keypoints[:, :, 2] == 0, :2] = 0.0
    bad = ~np.isfinite(keypoints).all(axis=(1, 2))
    if bad.any():
        ann_id = int(coco.ann_ids[kept][np.flatnonzero(bad)[0]])
        raise InputError(coco_path, f"annotation id {ann_id}.keypoints",
                         "lens distortion cannot be undone (a keypoint lies far outside the image)")
    appearance = None if coco.appearance is None else coco.appearance[kept]
    poses = Poses2D(keypoints, view[kept], coco.ann_ids[kept], coco.score[kept], appearance)
    return Scene(path.name, model.cameras, poses, model.points3d)


def write_scene(path: str | Path, cameras: Cameras, poses: Poses2D, binary: bool = True,
                points3d: np.ndarray | None = None) -> None:
    """Write a scene directory: a COLMAP model of ``cameras`` and ``poses2d.json`` (keypoints in
    the pinhole cameras' pixels). Each part is written atomically."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    atomic_replace_dir(lambda tmp: write_colmap(tmp, cameras, binary=binary, points3d=points3d),
                       path / SPARSE)
    document = coco_keypoints_document(cameras.names, cameras.size, poses.view, poses.keypoints,
                                       poses.score, poses.ids, poses.appearance)
    atomic_write_json(path / POSES2D, document)


def _finite_or_none(value: float, digits: int = 5):
    return round(float(value), digits) if math.isfinite(value) else None


def poses3d_document(persons: Persons3D, poses: Poses2D, metrics: dict, extra: dict | None = None) -> dict:
    """The ``mvm.poses3d/1`` document. ``members`` hold annotation ids of ``poses``."""
    out = []
    for p in range(len(persons)):
        kp = []
        for j in range(NUM_JOINTS):
            x = persons.keypoints3d[p, j]
            if np.all(np.isfinite(x)):
                kp.append([round(float(v), 6) for v in x] + [round(float(persons.scores[p, j]), 4)])
            else:
                kp.append([None, None, None, 0.0])
        out.append({
            "id": p,
            "keypoints3d": kp,
            "members": [int(poses.ids[m]) for m in persons.members[p]],
            "views_per_joint": [int(v) for v in persons.views_per_joint[p]],
            "outliers_per_joint": [int(v) for v in persons.outliers_per_joint[p]],
            "reprojection_error_px": _finite_or_none(persons.reprojection_error_px[p], 4),
        })
    document = {"format": POSES3D_FORMAT, "keypoints": list(COCO_KEYPOINTS), "persons": out,
                "metrics": {k: (_finite_or_none(v, 4) if isinstance(v, float) else v) for k, v in metrics.items()}}
    if extra:
        document.update(extra)
    return document


def write_poses3d(path: str | Path, document: dict) -> None:
    atomic_write_json(path, document, indent=1)


def read_poses3d(path: str | Path, poses: Poses2D | None = None) -> Persons3D:
    """Read ``poses3d.json``. With ``poses``, members are mapped back to indices into it;
    otherwise ``members`` hold the annotation ids."""
    path = Path(path)
    data = load_json(path)
    if not isinstance(data, dict) or data.get("format") != POSES3D_FORMAT:
        raise InputError(path, "format", f"expected {POSES3D_FORMAT!r}")
    persons = data.get("persons")
    if not isinstance(persons, list):
        raise InputError(path, "persons", "missing, or not a list")
    P = len(persons)
    X = np.full((P, NUM_JOINTS, 3), np.nan)
    scores = np.zeros((P, NUM_JOINTS))
    views = np.zeros((P, NUM_JOINTS), dtype=int)
    outliers = np.zeros((P, NUM_JOINTS), dtype=int)
    err = np.full(P, np.nan)
    members = []
    index = None if poses is None else {int(a): i for i, a in enumerate(poses.ids)}
    for p, person in enumerate(persons):
        field = f"persons[{p}]"
        if not isinstance(person, dict):
            raise InputError(path, field, "expected an object")
        kp = person.get("keypoints3d")
        if not isinstance(kp, list) or len(kp) != NUM_JOINTS:
            raise InputError(path, f"{field}.keypoints3d", f"expected a list of {NUM_JOINTS} [x, y, z, score]")
        for j, entry in enumerate(kp):
            where = f"{field}.keypoints3d[{j}]"
            if not isinstance(entry, list) or len(entry) != 4:
                raise InputError(path, where, "expected [x, y, z, score]")
            if entry[0] is not None:
                X[p, j] = numbers(entry[:3], path, where)
            elif entry[1] is not None or entry[2] is not None:
                raise InputError(path, where, "x, y and z must all be numbers or all null")
            scores[p, j] = number(entry[3], path, f"{where}[3]")
        for key, target in (("views_per_joint", views), ("outliers_per_joint", outliers)):
            values = person.get(key, [0] * NUM_JOINTS)
            if not isinstance(values, list) or len(values) != NUM_JOINTS:
                raise InputError(path, f"{field}.{key}", f"expected {NUM_JOINTS} integers")
            target[p] = [integer(v, path, f"{field}.{key}[{j}]") for j, v in enumerate(values)]
        if person.get("reprojection_error_px") is not None:
            err[p] = number(person["reprojection_error_px"], path, f"{field}.reprojection_error_px")
        ids = person.get("members", [])
        if not isinstance(ids, list):
            raise InputError(path, f"{field}.members", "expected a list of annotation ids")
        ids = [integer(a, path, f"{field}.members[{k}]") for k, a in enumerate(ids)]
        if index is not None:
            missing = [a for a in ids if a not in index]
            if missing:
                raise InputError(path, f"{field}.members", f"annotation id {missing[0]} not in poses2d.json")
            ids = [index[a] for a in ids]
        members.append(np.array(ids, dtype=np.int64))
    return Persons3D(X, scores, members, views, outliers, err)
