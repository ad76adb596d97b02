"""COLMAP models (text or binary): cameras of every registered image. A model of pinhole cameras
is built from what the checks of its files read (:mod:`mvm.io.colmap_check`); one with lenses, or
with rigs of several cameras, through pycolmap. A lens is converted to OpenCV's model when read
(:data:`OPENCV_LENSES`), so that every lens of mvm goes through :mod:`mvm.core.camera`."""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mvm.core.scene import Cameras
from mvm.errors import InputError
from mvm.io.colmap_check import check_model, model_files
from mvm.io.colmap_records import CAMERA_MODELS, PINHOLE_MODEL_IDS, ModelRecords

log = logging.getLogger(__name__)

#: COLMAP's camera models with a lens that OpenCV's models express: ``{name: (fisheye, indices of
#: the COLMAP parameters that give OpenCV's coefficients, in OpenCV's order, -1 for a zero)}``;
#: the focal lengths and principal point are the camera's ``K``. COLMAP's radial fisheye models
#: are OpenCV's fisheye model (``θ_d = θ (1 + k1 θ² + k2 θ⁴ + …)``), its plain fisheye models
#: that model without coefficients. The others (FOV, thin-prism, division, EUCM,
#: equirectangular) are refused.
OPENCV_LENSES = {
    "SIMPLE_RADIAL": (False, (3, -1, -1, -1)), "RADIAL": (False, (3, 4, -1, -1)),
    "OPENCV": (False, (4, 5, 6, 7)), "FULL_OPENCV": (False, tuple(range(4, 12))),
    "OPENCV_FISHEYE": (True, (4, 5, 6, 7)), "SIMPLE_RADIAL_FISHEYE": (True, (3, -1, -1, -1)),
    "RADIAL_FISHEYE": (True, (3, 4, -1, -1)), "SIMPLE_FISHEYE": (True, (-1, -1, -1, -1)),
    "FISHEYE": (True, (-1, -1, -1, -1)),
}


@dataclass(frozen=True)
class ColmapModel:
    """The registered images of a COLMAP model.

    Attributes:
        cameras: the registered images' cameras, their lenses in OpenCV's model
            (:data:`OPENCV_LENSES`).
        models: the COLMAP camera model of each registered image (``"PINHOLE"``, ``"OPENCV"``…).
        points3d: ``(M, 3)`` sparse points.
        unregistered: names of images in the model that have no pose.
    """

    cameras: Cameras
    models: tuple[str, ...]
    points3d: np.ndarray
    unregistered: tuple[str, ...]

    def index(self) -> dict[str, int]:
        return {name: i for i, name in enumerate(self.cameras.names)}


def find_model_dir(sparse: Path) -> Path:
    """``sparse/`` itself, or ``sparse/0`` as COLMAP's mapper writes it."""
    for candidate in (sparse, sparse / "0"):
        if any((candidate / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
            return candidate
    if not sparse.is_dir():
        raise InputError(sparse, None, "missing COLMAP model directory")
    raise InputError(sparse, None, "no COLMAP model: expected cameras/images/points3D .bin or .txt "
                                   "(in sparse/ or sparse/0/)")


def read_colmap(sparse: str | Path) -> ColmapModel:
    """Read a COLMAP model (text or binary) from ``sparse`` (or ``sparse/0``).

    The files are checked first (:func:`mvm.io.colmap_check.check_model`): a malformed model
    raises one :class:`InputError` instead of reaching pycolmap. A model of pinhole cameras is
    then built from what the checks read, without pycolmap (whose import costs 0.1–0.15 s, more
    than reading a two-minute video's model), others through pycolmap. A model whose files are
    byte for byte those of the model read last (the scenes of one rig, exported instant by
    instant, share their calibration) is not checked and parsed again: its cameras are copied.
    """
    model_dir = find_model_dir(Path(sparse))
    files = model_files(model_dir)
    global _last
    if _last is not None and _last[0] == files:
        model = _last[1]
    else:
        model = _parse(model_dir, check_model(model_dir, files))
        _last = files, model
    if model.unregistered:
        log.warning("%s: %d images have no pose and are ignored", model_dir, len(model.unregistered))
    c = model.cameras
    copied = replace(c, K=c.K.copy(), R=c.R.copy(), t=c.t.copy(), size=c.size.copy())
    return ColmapModel(copied, model.models, model.points3d.copy(), model.unregistered)


#: ``(files, model)``: the content of the model read last (:func:`model_files`) and what it gave.
_last: tuple[tuple[str, dict[str, bytes]], ColmapModel] | None = None


def _parse(model_dir: Path, records: ModelRecords | None = None) -> ColmapModel:
    """The model in ``model_dir``, its files already checked: from ``records`` (what the checks
    collected, :func:`_pinhole_model`) where that can be, else through pycolmap."""
    model = None if records is None else _pinhole_model(records, model_dir)
    if model is not None:
        return model
    import pycolmap

    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as e:  # pycolmap raises ValueError/RuntimeError with C++ context
        message = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(model_dir, None, f"cannot read COLMAP model: {message}") from None

    K, R, t, size, names, cams, lenses, unregistered = [], [], [], [], [], [], [], []
    for image_id in sorted(rec.images):
        image = rec.images[image_id]
        if not image.has_pose:
            unregistered.append(image.name)
            continue
        camera = rec.cameras[image.camera_id]
        pose = image.cam_from_world().matrix()
        _check_poses(model_dir, [image_id], pose[None, :, :3], pose[None, :, 3])
        K.append(camera.calibration_matrix())
        R.append(pose[:, :3])
        t.append(pose[:, 3])
        size.append((camera.width, camera.height))
        names.append(image.name)
        cams.append(camera)
        lenses.append(opencv_lens(camera.model.name, camera.params, model_dir, f"camera {image.camera_id}"))
    if len(set(names)) != len(names):
        raise InputError(model_dir, "images", "duplicate image names")
    points = np.array([p.xyz for p in rec.points3D.values()], dtype=float).reshape(-1, 3)
    V = len(names)
    cameras = Cameras(np.array(K).reshape(V, 3, 3), np.array(R).reshape(V, 3, 3),
                      np.array(t).reshape(V, 3), np.array(size, dtype=float).reshape(V, 2),
                      tuple(names), tuple(d for d, _ in lenses), np.array([f for _, f in lenses], dtype=bool))
    return ColmapModel(cameras, tuple(c.model.name for c in cams), points, tuple(unregistered))


def opencv_lens(model: str, params, path: Path, field: str) -> tuple[np.ndarray, bool]:
    """The lens of a COLMAP camera of ``model`` and ``params`` in OpenCV's model
    (:data:`OPENCV_LENSES`): its coefficients and whether it is OpenCV's fisheye model; no
    coefficients for a pinhole. A model OpenCV cannot express raises :class:`InputError`."""
    if model in ("SIMPLE_PINHOLE", "PINHOLE"):
        return np.zeros(0), False
    if model not in OPENCV_LENSES:
        raise InputError(path, field, f"camera model {model} has no OpenCV equivalent: undistort the images "
                                      f"(colmap image_undistorter), or use one of {', '.join(OPENCV_LENSES)}")
    fisheye, index = OPENCV_LENSES[model]
    params = np.append(np.asarray(params, dtype=float), 0.0)                   # index -1: a zero
    return params[list(index)], fisheye


def _pinhole_model(records: ModelRecords, model_dir: Path) -> ColmapModel | None:
    """The model whose files gave ``records``, as pycolmap reads it, where every camera is a
    pinhole (:data:`~mvm.io.colmap_records.PINHOLE_MODEL_IDS`) and every rig one camera (an
    image's pose is then its frame's, or in a model without frames its own); else None. Images
    in the order of their ids; a quaternion far from unit length is refused, as pycolmap's
    matrix of it is no rotation (:func:`_check_poses`)."""
    if not records.one_camera_rigs or any(c[0] not in PINHOLE_MODEL_IDS for c in records.cameras.values()):
        return None
    ids = sorted(records.images)
    poses = records.frame_poses if records.frames is not None else {i: records.images[i][0] for i in ids}
    pose = np.array([poses[i] for i in ids], dtype=float).reshape(-1, 7)
    cams = [records.cameras[records.images[i][1]] for i in ids]
    params = [c[3] if c[0] == 1 else (c[3][0], c[3][0], c[3][1], c[3][2]) for c in cams]   # fx, fy, cx, cy
    f = np.array(params, dtype=float).reshape(-1, 4)
    K = np.zeros((len(ids), 3, 3))
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = f[:, 0], f[:, 1], f[:, 2], f[:, 3], 1.0
    R = rotation_matrices(pose[:, :4])
    _check_poses(model_dir, ids, R, pose[:, 4:])
    cameras = Cameras(K, R, pose[:, 4:].copy(),
                      np.array([c[1:3] for c in cams], dtype=float).reshape(-1, 2),
                      tuple(records.images[i][2] for i in ids))
    return ColmapModel(cameras, tuple(CAMERA_MODELS[c[0]][0] for c in cams),
                       np.array(records.points, dtype=float).reshape(-1, 3), ())


def _check_poses(model_dir: Path, ids: list[int], R: np.ndarray, t: np.ndarray) -> None:
    """Refuse the first image of ``ids`` whose ``R: (n, 3, 3)``, ``t: (n, 3)`` is not a finite
    rotation and translation (one :class:`InputError` naming it)."""
    with np.errstate(invalid="ignore", over="ignore"):
        bad = ~(np.isfinite(R).all((1, 2)) & np.isfinite(t).all(1)
                & (np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max((1, 2), initial=0.0) <= 1e-6))
    if bad.any():
        raise InputError(model_dir, f"image {ids[int(np.argmax(bad))]}",
                         "pose is not a finite rotation and translation")


def rotation_matrices(q: np.ndarray) -> np.ndarray:
    """The matrices ``(n, 3, 3)`` of quaternions ``q: (n, 4)`` (w, x, y, z), as Eigen computes
    them (a rotation for a unit quaternion).

    >>> rotation_matrices(np.array([[0.0, 0, 0, 1]]))[0].tolist()
    [[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    w, x, y, z = np.asarray(q, dtype=float).T
    tx, ty, tz = 2 * x, 2 * y, 2 * z
    twx, twy, twz, txx, txy, txz, tyy, tyz, tzz = tx * w, ty * w, tz * w, tx * x, ty * x, tz * x, ty * y, tz * y, tz * z
    return np.stack([1 - (tyy + tzz), txy - twz, txz + twy,
                     txy + twz, 1 - (txx + tzz), tyz - twx,
                     txz - twy, tyz + twx, 1 - (txx + tyy)], -1).reshape(-1, 3, 3)


def write_colmap(path: str | Path, cameras: Cameras, binary: bool = True,
                 points3d: np.ndarray | None = None) -> None:
    """Write pinhole ``cameras`` as a COLMAP model into directory ``path`` (one camera per
    distinct intrinsics)."""
    import pycolmap

    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    rec = pycolmap.Reconstruction()
    camera_ids: dict[tuple, int] = {}
    for i, name in enumerate(cameras.names):
        K, (w, h) = cameras.K[i], cameras.size[i]
        key = (round(K[0, 0], 6), round(K[1, 1], 6), round(K[0, 2], 6), round(K[1, 2], 6), int(w), int(h))
        if key not in camera_ids:
            camera_ids[key] = len(camera_ids) + 1
            camera = pycolmap.Camera(model="PINHOLE", width=int(w), height=int(h),
                                     params=list(key[:4]), camera_id=camera_ids[key])
            rec.add_camera_with_trivial_rig(camera)
        image = pycolmap.Image(name=name, camera_id=camera_ids[key], image_id=i + 1)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(cameras.R[i]), cameras.t[i])
        rec.add_image_with_trivial_frame(image, pose)
    if points3d is not None:
        for xyz in np.asarray(points3d, dtype=float).reshape(-1, 3):
            rec.add_point3D(xyz, pycolmap.Track(), np.zeros(3, dtype=np.uint8))
    if binary:
        rec.write_binary(str(path))
    else:
        rec.write_text(str(path))
