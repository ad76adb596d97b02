"""What the checks of a COLMAP model's files collect and check on the way: the known camera
models, the values mvm relies on (camera parameters, poses, image names, sensors, frames, point
tracks) and the references between files. Each problem raises one
:class:`~mvm.errors.InputError` naming the file and the record. What they collect (cameras,
poses, names, points) is enough to build a model of pinhole cameras without pycolmap
(:func:`mvm.io.colmap.read_colmap`)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.checks import MAX_COORDINATE
from mvm.io.paths import name_problem

FILES = ("cameras", "images", "points3D")
OPTIONAL_FILES = ("rigs", "frames")
SENSOR_TYPES = {"INVALID": -1, "CAMERA": 0, "IMU": 1}


#: COLMAP's camera models (``src/colmap/sensor/models.h``; pycolmap 4.2): ``{model id: (name,
#: number of parameters, focal indices)}``. Models of a newer COLMAP are looked up in the installed
#: pycolmap (:func:`camera_models`).
CAMERA_MODELS = {
    0: ("SIMPLE_PINHOLE", 3, (0,)), 1: ("PINHOLE", 4, (0, 1)), 2: ("SIMPLE_RADIAL", 4, (0,)),
    3: ("RADIAL", 5, (0,)), 4: ("OPENCV", 8, (0, 1)), 5: ("OPENCV_FISHEYE", 8, (0, 1)),
    6: ("FULL_OPENCV", 12, (0, 1)), 7: ("FOV", 5, (0, 1)), 8: ("SIMPLE_RADIAL_FISHEYE", 4, (0,)),
    9: ("RADIAL_FISHEYE", 5, (0,)), 10: ("THIN_PRISM_FISHEYE", 12, (0, 1)),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16, (0, 1)), 12: ("SIMPLE_DIVISION", 4, (0,)),
    13: ("DIVISION", 5, (0, 1)), 14: ("SIMPLE_FISHEYE", 3, (0,)), 15: ("FISHEYE", 4, (0, 1)),
    16: ("EUCM", 6, (0, 1)), 17: ("EQUIRECTANGULAR", 2, ()),
}

#: The pinhole models, whose cameras are their ``K``: read without pycolmap.
PINHOLE_MODEL_IDS = frozenset({0, 1})


def camera_models(wanted: int | str | None = None) -> dict[int, tuple[str, int, tuple[int, ...]]]:
    """COLMAP camera models: ``{model id: (name, number of parameters, focal indices)}``,
    :data:`CAMERA_MODELS`, or where ``wanted`` (a model id or name) is not among them, the
    installed pycolmap's models (imported only then)."""
    if wanted is None or wanted in CAMERA_MODELS or any(m[0] == wanted for m in CAMERA_MODELS.values()):
        return CAMERA_MODELS
    return {**CAMERA_MODELS, **pycolmap_camera_models()}


@lru_cache(maxsize=1)
def pycolmap_camera_models() -> dict[int, tuple[str, int, tuple[int, ...]]]:
    """The camera models of the installed pycolmap, as :data:`CAMERA_MODELS` lists them."""
    import pycolmap

    models = {}
    for name, model_id in pycolmap.CameraModelId.__members__.items():
        if name == "INVALID":
            continue
        camera = pycolmap.Camera.create_from_model_name(1, name, 1.0, 1, 1)
        models[int(model_id)] = (name, len(camera.params), tuple(camera.focal_length_idxs()))
    return models



@dataclass
class ModelRecords:
    """What the checks collect on the way, to check references between files."""

    camera_ids: set = field(default_factory=set)
    rig_ids: set = field(default_factory=set)
    image_ids: set = field(default_factory=set)
    names: dict = field(default_factory=dict)
    points2d: dict = field(default_factory=dict)        # image id -> number of 2D points
    rig_sensors: dict = field(default_factory=dict)     # rig id -> {(sensor type, sensor id)}
    frames: Path | None = None                           # the frames file, once read
    frame_images: dict = field(default_factory=dict)    # image id -> (record in frames, camera id)
    cameras: dict = field(default_factory=dict)         # camera id -> (model id, width, height, params)
    images: dict = field(default_factory=dict)          # image id -> (pose, camera id, name)
    frame_poses: dict = field(default_factory=dict)     # image id -> its frame's pose (rig from world)
    one_camera_rigs: bool = True                         # every rig is one sensor, its reference
    points: list = field(default_factory=list)          # (x, y, z) of every 3D point


def check_camera(model: ModelRecords, path, where, camera_id, model_id, width, height, params) -> None:
    models = camera_models(model_id)
    if camera_id in model.camera_ids:
        raise InputError(path, where, f"duplicate camera id {camera_id}")
    if model_id not in models:
        raise InputError(path, where, f"unknown camera model {model_id}")
    name, n_params, focal = models[model_id]
    if not focal:
        raise InputError(path, where, f"camera model {name} has no focal length: not supported")
    if len(params) != n_params:
        raise InputError(path, where, f"camera model {name} takes {n_params} parameters, got {len(params)}")
    if not all(math.isfinite(p) for p in params):
        raise InputError(path, where, "camera parameters are not finite")
    if any(abs(p) > MAX_COORDINATE for p in params):
        raise InputError(path, where, f"a camera parameter is beyond ±{MAX_COORDINATE:g}")
    if any(params[i] <= 0 for i in focal):
        raise InputError(path, where, f"focal length must be > 0, got {params[focal[0]]:g}")
    if not (0 < width < 2 ** 31 and 0 < height < 2 ** 31):
        raise InputError(path, where, f"image size must be > 0, got {width} × {height}")
    model.camera_ids.add(camera_id)
    model.cameras[camera_id] = (model_id, width, height, tuple(params))


def check_position(path, where, xyz) -> None:
    if not all(math.isfinite(v) for v in xyz):
        raise InputError(path, where, "position is not finite")
    if any(abs(v) > MAX_COORDINATE for v in xyz):
        raise InputError(path, where, f"position beyond ±{MAX_COORDINATE:g} model units")


def check_pose(path, where, values) -> None:
    """``values``: qw, qx, qy, qz, tx, ty, tz."""
    if not all(math.isfinite(v) for v in values):
        raise InputError(path, where, "pose is not finite")
    norm = math.hypot(*values[:4])
    if norm < 1e-8:
        raise InputError(path, where, "zero-norm quaternion")
    if not 1e-8 < norm < 1e150:
        raise InputError(path, where, f"quaternion norm {norm:g} is out of range")
    if any(abs(v) > MAX_COORDINATE for v in values[4:]):
        raise InputError(path, where, f"translation beyond ±{MAX_COORDINATE:g} model units")


def check_image(model: ModelRecords, path, where, image_id, pose, camera_id, name) -> None:
    if image_id in model.image_ids:
        raise InputError(path, where, f"duplicate image id {image_id}")
    check_pose(path, where, pose)
    if camera_id not in model.camera_ids:
        raise InputError(path, where, f"camera {camera_id} is not in cameras")
    problem = name_problem(name)
    if problem:
        raise InputError(path, where, problem)
    if name in model.names:
        raise InputError(path, where, f"duplicate image name {name!r}")
    if model.frames is not None:
        if image_id not in model.frame_images:
            raise InputError(path, where, f"image {image_id} ({name}) is in no frame of {model.frames.name} "
                                          "(every image of a COLMAP 3.12 model belongs to a frame)")
        frame, sensor = model.frame_images[image_id]
        if sensor != camera_id:
            raise InputError(path, where, f"image {image_id} ({name}) has camera {camera_id}, its frame "
                                          f"({model.frames.name}, {frame}) lists it under camera {sensor}")
    model.image_ids.add(image_id)
    model.names[name] = image_id
    model.images[image_id] = (tuple(pose), camera_id, name)


def check_sensor_type(path, where, value) -> None:
    if value not in SENSOR_TYPES.values():
        raise InputError(path, where, f"unknown sensor type {value}")


def check_frame(model: ModelRecords, path, where, rig_id, data_ids, pose) -> None:
    """One frame's ``data_ids``: (sensor type, sensor id, data id); every sensor is one of its
    rig's, and each camera's data id (an image id) is recorded for the images to be checked,
    with the frame's ``pose`` (qw, qx, qy, qz, tx, ty, tz, the rig from the world)."""
    sensors = model.rig_sensors.get(rig_id)
    names = {v: k for k, v in SENSOR_TYPES.items()}
    for sensor_type, sensor_id, data_id in data_ids:
        if sensors is not None and (sensor_type, sensor_id) not in sensors:
            raise InputError(path, where, f"sensor {names.get(sensor_type, sensor_type)} {sensor_id} is not "
                                          f"in rig {rig_id}")
        if sensor_type == SENSOR_TYPES["CAMERA"]:
            if data_id in model.frame_images:
                raise InputError(path, where, f"image {data_id} is in two frames")
            model.frame_images[data_id] = (where, sensor_id)
            model.frame_poses[data_id] = tuple(pose)


def check_track(model: ModelRecords, path, where, track: np.ndarray) -> None:
    """A point's track ``(n, 2)`` of (IMAGE_ID, POINT2D_IDX): every image exists and every
    index is below that image's number of 2D points (pycolmap would stop in a C++ range check)."""
    for image_id, idx in track.tolist():
        count = model.points2d.get(image_id)
        if count is None:
            raise InputError(path, where, f"track: image {image_id} is not in images")
        if idx >= count:
            raise InputError(path, where, f"track: 2D point index {idx} of image {image_id} is out of range "
                                          f"(the image has {count} 2D points)")
