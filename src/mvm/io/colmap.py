"""COLMAP models (text or binary) through pycolmap: cameras of every registered image."""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.core.scene import Cameras
from mvm.errors import InputError
from mvm.io.colmap_check import check_model, model_files

log = logging.getLogger(__name__)

_PINHOLE_MODELS = {"SIMPLE_PINHOLE", "PINHOLE"}


@dataclass(frozen=True)
class ColmapModel:
    """The registered images of a COLMAP model.

    Attributes:
        cameras: the registered images' pinhole cameras (distortion is undone on keypoints).
        colmap_cameras: the pycolmap camera of each registered image, for undistortion.
        points3d: ``(M, 3)`` sparse points.
        unregistered: names of images in the model that have no pose.
    """

    cameras: Cameras
    colmap_cameras: tuple
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
    raises one :class:`InputError` instead of reaching pycolmap. A model whose files are
    byte for byte those of the model read last (the scenes of one rig, exported instant by
    instant, share their calibration) is not checked and parsed again: its cameras are copied.
    """
    model_dir = find_model_dir(Path(sparse))
    files = model_files(model_dir)
    global _last
    if _last is not None and _last[0] == files:
        model = _last[1]
    else:
        check_model(model_dir, files)
        model = _parse(model_dir)
        _last = files, model
    if model.unregistered:
        log.warning("%s: %d images have no pose and are ignored", model_dir, len(model.unregistered))
    cameras = model.cameras
    copied = Cameras(cameras.K.copy(), cameras.R.copy(), cameras.t.copy(), cameras.size.copy(), cameras.names)
    return ColmapModel(copied, model.colmap_cameras, model.points3d.copy(), model.unregistered)


#: ``(files, model)``: the content of the model read last (:func:`model_files`) and what it gave.
_last: tuple[tuple[str, dict[str, bytes]], ColmapModel] | None = None


def _parse(model_dir: Path) -> ColmapModel:
    """The model in ``model_dir`` through pycolmap (its files already checked)."""
    import pycolmap

    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as e:  # pycolmap raises ValueError/RuntimeError with C++ context
        message = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(model_dir, None, f"cannot read COLMAP model: {message}") from None

    K, R, t, size, names, cams, unregistered = [], [], [], [], [], [], []
    for image_id in sorted(rec.images):
        image = rec.images[image_id]
        if not image.has_pose:
            unregistered.append(image.name)
            continue
        camera = rec.cameras[image.camera_id]
        pose = image.cam_from_world().matrix()
        if not np.all(np.isfinite(pose)) or np.abs(pose[:, :3] @ pose[:, :3].T - np.eye(3)).max() > 1e-6:
            raise InputError(model_dir, f"image {image_id}", "pose is not a finite rotation and translation")
        K.append(camera.calibration_matrix())
        R.append(pose[:, :3])
        t.append(pose[:, 3])
        size.append((camera.width, camera.height))
        names.append(image.name)
        cams.append(camera)
    if len(set(names)) != len(names):
        raise InputError(model_dir, "images", "duplicate image names")
    points = np.array([p.xyz for p in rec.points3D.values()], dtype=float).reshape(-1, 3)
    V = len(names)
    cameras = Cameras(np.array(K).reshape(V, 3, 3), np.array(R).reshape(V, 3, 3),
                      np.array(t).reshape(V, 3), np.array(size, dtype=float).reshape(V, 2),
                      tuple(names))
    return ColmapModel(cameras, tuple(cams), points, tuple(unregistered))


def undistort_keypoints(model: ColmapModel, view: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Undo lens distortion. ``view: (N,)``, ``xy: (N, J, 2)`` pixels -> ``(N, J, 2)`` pixels of
    each view's pinhole camera ``K``."""
    out = np.array(xy, dtype=float)
    for v in np.unique(view):
        camera = model.colmap_cameras[v]
        if camera.model.name in _PINHOLE_MODELS:
            continue
        rows = view == v
        pts = out[rows].reshape(-1, 2)
        normalized = np.asarray(camera.cam_from_img(pts), dtype=float)
        homogeneous = np.concatenate([normalized, np.ones((len(normalized), 1))], axis=1)
        pixels = homogeneous @ model.cameras.K[v].T
        out[rows] = pixels[:, :2].reshape(out[rows].shape)
    return out


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
