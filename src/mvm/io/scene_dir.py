"""The scene directory: ``sparse/`` + ``poses2d.json`` in, ``mvm/poses3d.json`` out (its layout:
:mod:`mvm.io.layout`)."""
from __future__ import annotations

import logging
import os
import posixpath
from pathlib import Path

import numpy as np

from mvm.core.camera import undistort_views
from mvm.core.completion import FLAG_NAMES, MISSING, OBSERVED, flag_names, parse_flags
from mvm.core.keypoints import COCO_KEYPOINTS, NUM_JOINTS
from mvm.core.scene import Cameras, Persons3D, Poses2D, Scene
from mvm.errors import InputError
from mvm.io.checks import MAX_COORDINATE, inside_root, integer, load_json, number, numbers
from mvm.io.coco import coco_keypoints_document, read_coco_keypoints
from mvm.io.colmap import read_colmap, write_colmap
from mvm.io.files import OutputError, atomic_write_json, json_number
from mvm.io.layout import DEFAULT_OUTPUT, FRAMES, POSES2D, POSES3D, SPARSE, TIMINGS
from mvm.io.outputs import atomic_replace_dir, writing_into
from mvm.io.paths import check_name, resolve_in

log = logging.getLogger(__name__)

POSES3D_FORMAT = "mvm.poses3d/1"


def read_scene(path: str | Path) -> Scene:
    """Read a scene directory into a :class:`Scene` (keypoints undistorted, unregistered
    images' poses dropped with a warning).

    ``poses2d.json`` is read the guarded way (a regular file of bounded size inside the scene:
    a FIFO, ``/dev/zero`` or a link leading out is refused before anything is read).
    Image names (COCO ``file_name``, COLMAP ``NAME``) name files of ``frames/``: a name that is
    absolute, climbs out with ``..``, or resolves through a symbolic link to a place outside
    the scene directory is refused (:func:`mvm.io.paths.resolve_in`).
    """
    path = Path(path)
    if not path.is_dir():
        raise InputError(path, None, "not a scene directory (expected sparse/ and poses2d.json)")
    model = read_colmap(path / SPARSE)
    coco_path = path / POSES2D
    coco = read_coco_keypoints(coco_path, root=path)
    view_of_name = model.index()
    unregistered = set(model.unregistered)
    image_view = np.full(len(coco.file_names), -1)
    # Below a frames/ folder that does not exist nothing can be a link: the names' own checks suffice.
    frames_absent = not os.path.lexists(path / FRAMES)
    for i, name in enumerate(coco.file_names):
        if frames_absent:
            check_name(name, coco_path, f"images[{i}].file_name")
        else:
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
    keypoints[:, :, :2] = undistort_views(model.cameras, keypoints[:, :, :2], view[kept])
    keypoints[keypoints[:, :, 2] == 0, :2] = 0.0
    bad = ~np.isfinite(keypoints).all(axis=(1, 2))
    if bad.any():
        ann_id = int(coco.ann_ids[kept][np.flatnonzero(bad)[0]])
        raise InputError(coco_path, f"annotation id {ann_id}.keypoints",
                         "lens distortion cannot be undone (a keypoint lies far outside the image)")
    appearance = None if coco.appearance is None else coco.appearance[kept]
    poses = Poses2D(keypoints, view[kept], coco.ann_ids[kept], coco.score[kept], appearance)
    return Scene(path.name, model.cameras, poses, model.points3d)


def scene_inputs(scene: str | Path, output: str = DEFAULT_OUTPUT) -> list[Path]:
    """What a command reading a reconstructed scene reads, for
    :func:`mvm.io.outputs.check_output_location`: every entry of the scene folder but the one
    holding its output folder (``frames/``, ``sparse/``, ``poses2d.json``, videos, ...), and the
    output folder's ``poses3d.json`` and ``timings.json`` (the page reads both)."""
    scene = Path(scene)
    out = scene / output
    entries = sorted(p for p in scene.iterdir() if not (p == out or p in out.parents)) if scene.is_dir() else []
    return [*entries, out / POSES3D, out / TIMINGS]


#: The reconstruction's name in the reasons of a rerun (:mod:`mvm.io.provenance`).
RECONSTRUCT_STAGE = "the reconstruction"


def reconstruct_settings(config, metric_scale: bool) -> dict:
    """The settings the record of a scene's ``poses3d.json`` keeps (:mod:`mvm.io.provenance`):
    the reconstruction's (``config``, a :class:`~mvm.core.config.Config` as the scene driver
    uses it) and whether the world was scaled to metres."""
    from dataclasses import asdict

    return {"config": asdict(config), "metric_scale": bool(metric_scale)}


def reconstruction_inputs(scene: str | Path) -> dict[str, Path]:
    """What a scene's ``poses3d.json`` is made from (:mod:`mvm.io.provenance`): ``poses2d.json``
    and the camera model in ``sparse/``."""
    scene = Path(scene)
    return {POSES2D: scene / POSES2D, SPARSE: scene / SPARSE}


def check_reconstruction_fresh(scene: str | Path, poses3d: str | Path) -> None:
    """Refuse to read a ``poses3d.json`` whose ``poses2d.json`` or ``sparse/`` changed since it
    was made (its record says so): one line naming the command that brings it up to date."""
    from mvm.io.provenance import check_fresh

    check_fresh(poses3d, reconstruction_inputs(scene),
                f"mvm reconstruct {scene}` (or `mvm run` again, for a scene made from a video)")


def output_dir(scene: str | Path, output: str = DEFAULT_OUTPUT) -> Path:
    """The folder ``scene/output`` that receives a scene's results, checked before any work:
    ``output`` is a relative name that stays in the scene, not one of its inputs (``frames/``,
    ``sparse/``, ``poses2d.json``), and an existing ``scene/output``
    must be a folder that, every symbolic link resolved, lies inside the scene directory
    (:class:`~mvm.io.files.OutputError` otherwise). It is created by the first write."""
    scene = Path(scene)
    check_name(output, "--output-name", "output folder name")
    path = scene / output
    if posixpath.normpath(output.replace("\\", "/")).split("/")[0] in (FRAMES, SPARSE, POSES2D):
        raise OutputError(path, None, "is an input of the scene (frames/, sparse/, poses2d.json): "
                                      "choose another output folder name")
    if path.is_symlink() or path.exists():
        try:
            inside_root(path, scene)
        except InputError as e:
            raise OutputError(path, None, f"refusing to write: {e.problem}") from None
        if not path.is_dir():
            raise OutputError(path, None, "cannot write: exists and is not a folder")
    return path


def write_scene(path: str | Path, cameras: Cameras, poses: Poses2D, binary: bool = True,
                points3d: np.ndarray | None = None) -> None:
    """Write a scene directory: a COLMAP model of ``cameras`` and ``poses2d.json`` (keypoints in
    the pinhole cameras' pixels). Each part is written atomically; a ``sparse/`` or
    ``poses2d.json`` that mvm did not write there is refused before any write
    (:func:`mvm.io.outputs.writing_into`)."""
    path = Path(path)
    document = coco_keypoints_document(cameras.names, cameras.size, poses.view, poses.keypoints,
                                       poses.score, poses.ids, poses.appearance)
    with writing_into(path, [SPARSE, POSES2D]):       # a user's sparse/ or poses2d.json: refused
        atomic_replace_dir(lambda tmp: write_colmap(tmp, cameras, binary=binary, points3d=points3d),
                           path / SPARSE, replace_unmarked=True)
        atomic_write_json(path / POSES2D, document)


def poses3d_document(persons: Persons3D, poses: Poses2D, metrics: dict, extra: dict | None = None) -> dict:
    """The ``mvm.poses3d/1`` document. ``members`` hold annotation ids of ``poses``. Numbers
    follow the writer policy (:func:`mvm.io.files.json_number`): coordinates keep 10
    significant digits whatever the model's unit, and a non-finite value is ``null``."""
    X = np.asarray(persons.keypoints3d, dtype=float)
    coords, scores = X.tolist(), np.asarray(persons.scores, dtype=float).tolist()       # plain floats, one pass
    finite = np.isfinite(X).all(-1).tolist() if X.size else []
    ids = np.asarray(poses.ids).tolist()
    missing = [None, None, None, 0.0]
    out = []
    for p in range(len(persons)):
        kp = [[json_number(c[0]), json_number(c[1]), json_number(c[2]), round(score, 4)] if ok else list(missing)
              for c, score, ok in zip(coords[p][:NUM_JOINTS], scores[p], finite[p])]
        out.append({
            "id": p,
            "keypoints3d": kp,
            "members": [ids[m] for m in np.asarray(persons.members[p]).tolist()],
            "views_per_joint": np.asarray(persons.views_per_joint[p]).astype(int).tolist(),
            "outliers_per_joint": np.asarray(persons.outliers_per_joint[p]).astype(int).tolist(),
            "reprojection_error_px": json_number(persons.reprojection_error_px[p], 6),
        })
        if persons.flags is not None:
            out[-1]["flags"] = flag_names(persons.flags[p])
    document = {"format": POSES3D_FORMAT, "keypoints": list(COCO_KEYPOINTS), "persons": out,
                "metrics": {k: (json_number(v, 6) if isinstance(v, float) else v) for k, v in metrics.items()}}
    if extra:
        document.update(extra)
    return document


def write_poses3d(path: str | Path, document: dict) -> None:
    atomic_write_json(path, document, pretty=True)


def load_poses3d_document(path: str | Path, root: str | Path | None = None) -> dict:
    """The ``mvm.poses3d/1`` document of ``path`` (read by the guarded reader, inside ``root``
    when given), its format and ``metrics`` checked: every metric is a finite number, null,
    a string or a list/object of those."""
    data = load_json(path, root)
    if not isinstance(data, dict) or data.get("format") != POSES3D_FORMAT:
        raise InputError(path, "format", f"expected {POSES3D_FORMAT!r}")
    metrics = data.get("metrics", {})
    if not isinstance(metrics, dict):
        raise InputError(path, "metrics", "expected an object")
    for key, value in metrics.items():
        _check_metric(value, path, f"metrics.{key}")
    return data


def _check_metric(value, path, field) -> None:
    if value is None or isinstance(value, (str, bool)):
        return
    if isinstance(value, (int, float)):
        number(value, path, field)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _check_metric(v, path, f"{field}[{i}]")
    elif isinstance(value, dict):
        for k, v in value.items():
            _check_metric(v, path, f"{field}.{k}")


def read_poses3d(path: str | Path, poses: Poses2D | None = None, root: str | Path | None = None) -> Persons3D:
    """Read ``poses3d.json``. With ``poses``, members are mapped back to indices into it;
    otherwise ``members`` hold the annotation ids."""
    path = Path(path)
    return parse_poses3d(load_poses3d_document(path, root), path, poses)


def parse_poses3d(data: dict, path: str | Path, poses: Poses2D | None = None) -> Persons3D:
    """The persons of a document from :func:`load_poses3d_document` (``path`` names it in errors)."""
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
    flags = np.where(np.isfinite(X[..., 0]), OBSERVED, MISSING).astype(np.int8)
    has_flags = False
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
                if np.abs(X[p, j]).max() > MAX_COORDINATE:
                    raise InputError(path, where, f"coordinate beyond ±{MAX_COORDINATE:g} model units")
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
        if "flags" in person:
            flags[p] = _flags(person["flags"], X[p], path, f"{field}.flags")
            has_flags = True
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
    return Persons3D(X, scores, members, views, outliers, err, flags if has_flags else None)


def _flags(value, X: np.ndarray, path: Path, field: str) -> np.ndarray:
    """A person's ``flags`` (17 names) checked against its joints ``X: (17, 3)``."""
    if not isinstance(value, list) or len(value) != NUM_JOINTS:
        raise InputError(path, field, f"expected a list of {NUM_JOINTS} names ({', '.join(FLAG_NAMES)})")
    try:
        flags = parse_flags(value, field)
    except ValueError as e:
        raise InputError(path, field, str(e).split(": ", 1)[1]) from None
    bad = np.flatnonzero((flags == MISSING) == np.isfinite(X).all(-1))
    if len(bad):
        raise InputError(path, f"{field}[{bad[0]}]", "'missing' must go with null coordinates, and only with them")
    return flags
