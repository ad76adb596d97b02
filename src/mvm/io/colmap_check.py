"""Check the files of a COLMAP model before pycolmap reads them.

pycolmap trusts the counts and lengths in a model: a binary file truncated inside an image
name, or a count of 2^32 records, makes it loop for hours, and a text ``frames.txt`` with a
huge ``NUM_DATA_IDS`` does the same. So every file is walked here first, with each count
checked against the bytes (or tokens) that remain, and the values mvm relies on are checked
too: known camera models with the right number of finite parameters, positive image sizes
and focal lengths, finite non-zero quaternions, finite translations and points, image names
that are UTF-8, unique and relative (:mod:`mvm.io.paths`), and ids that refer to something.

Layouts: COLMAP's ``src/colmap/scene/reconstruction_io_{binary,text}.cc`` (3.12+, with
``rigs`` and ``frames``; older models without them are read too). Every problem raises one
:class:`~mvm.errors.InputError`: ``FILE: FIELD: PROBLEM`` where FIELD is ``line N`` in a
text file and the record (``image 3``, ``camera 1``…) in a binary one.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.checks import MAX_COORDINATE, read_bytes
from mvm.io.paths import name_problem

FILES = ("cameras", "images", "points3D")
OPTIONAL_FILES = ("rigs", "frames")
SENSOR_TYPES = {"INVALID": -1, "CAMERA": 0, "IMU": 1}


@lru_cache(maxsize=1)
def camera_models() -> dict[int, tuple[str, int, tuple[int, ...]]]:
    """COLMAP camera models: ``{model id: (name, number of parameters, focal indices)}``."""
    import pycolmap

    models = {}
    for name, model_id in pycolmap.CameraModelId.__members__.items():
        if name == "INVALID":
            continue
        camera = pycolmap.Camera.create_from_model_name(1, name, 1.0, 1, 1)
        models[int(model_id)] = (name, len(camera.params), tuple(camera.focal_length_idxs()))
    return models


def model_format(model_dir: Path) -> str:
    """``"bin"`` or ``"txt"``: the format pycolmap will read from ``model_dir``."""
    for ext in ("bin", "txt"):
        if all((model_dir / f"{name}.{ext}").is_file() for name in FILES):
            return ext
    ext = "bin" if (model_dir / "cameras.bin").is_file() else "txt"
    missing = [f"{name}.{ext}" for name in FILES if not (model_dir / f"{name}.{ext}").is_file()]
    raise InputError(model_dir, None, f"incomplete COLMAP model: missing {', '.join(missing)}")


@dataclass
class _Model:
    """What the checks collect on the way, to check references between files."""

    camera_ids: set = field(default_factory=set)
    rig_ids: set = field(default_factory=set)
    image_ids: set = field(default_factory=set)
    names: dict = field(default_factory=dict)
    points2d: dict = field(default_factory=dict)        # image id -> number of 2D points
    rig_sensors: dict = field(default_factory=dict)     # rig id -> {(sensor type, sensor id)}
    frames: Path | None = None                           # the frames file, once read
    frame_images: dict = field(default_factory=dict)    # image id -> (record in frames, camera id)


def model_files(model_dir: str | Path) -> tuple[str, dict[str, bytes]]:
    """The format of the COLMAP model in ``model_dir`` (``bin``/``txt``) and the content of
    each of its files, in the order they are checked: ``{"cameras": b"...", ...}`` (the
    optional ``rigs`` and ``frames`` where present). Files are read the guarded way
    (:func:`mvm.io.checks.read_bytes`)."""
    model_dir = Path(model_dir)
    ext = model_format(model_dir)
    files = {}
    for name in OPTIONAL_FILES[:1] + FILES[:1] + OPTIONAL_FILES[1:] + FILES[1:]:
        path = model_dir / f"{name}.{ext}"
        if name in OPTIONAL_FILES and not (path.exists() or path.is_symlink()):
            continue
        files[name] = read_bytes(path)
    return ext, files


def check_model(model_dir: str | Path, files: tuple[str, dict[str, bytes]] | None = None) -> str:
    """Check every file of the COLMAP model in ``model_dir``; return its format (``bin``/``txt``).
    ``files``: what :func:`model_files` read of it, else it is read here."""
    model_dir = Path(model_dir)
    ext, content = files or model_files(model_dir)
    model = _Model()
    check = _BINARY if ext == "bin" else _TEXT
    for name, data in content.items():
        check[name](data, model_dir / f"{name}.{ext}", model)
    rigs, frames = (name in content for name in OPTIONAL_FILES)
    if rigs != frames:
        have, need = ("rigs", "frames") if rigs else ("frames", "rigs")
        raise InputError(model_dir / f"{need}.{ext}", None,
                         f"missing: a model with {have}.{ext} (COLMAP 3.12 layout) needs {need}.{ext} too")
    for image_id, (where, _) in model.frame_images.items():
        if image_id not in model.image_ids:
            raise InputError(model.frames, where, f"image {image_id} is not in images.{ext}")
    return ext


# --- values --------------------------------------------------------------------------------

def _camera(model: _Model, path, where, camera_id, model_id, width, height, params) -> None:
    models = camera_models()
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


def _position(path, where, xyz) -> None:
    if not all(math.isfinite(v) for v in xyz):
        raise InputError(path, where, "position is not finite")
    if any(abs(v) > MAX_COORDINATE for v in xyz):
        raise InputError(path, where, f"position beyond ±{MAX_COORDINATE:g} model units")


def _pose(path, where, values) -> None:
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


def _image(model: _Model, path, where, image_id, pose, camera_id, name) -> None:
    if image_id in model.image_ids:
        raise InputError(path, where, f"duplicate image id {image_id}")
    _pose(path, where, pose)
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


def _sensor_type(path, where, value) -> None:
    if value not in SENSOR_TYPES.values():
        raise InputError(path, where, f"unknown sensor type {value}")


def _frame(model: _Model, path, where, rig_id, data_ids) -> None:
    """One frame's ``data_ids``: (sensor type, sensor id, data id); every sensor is one of its
    rig's, and each camera's data id (an image id) is recorded for the images to be checked."""
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


# --- binary --------------------------------------------------------------------------------

class _Reader:
    """Little-endian values from ``data``; running out raises InputError naming ``record``."""

    def __init__(self, data: bytes, path: Path):
        self.data, self.path, self.offset, self.record = data, path, 0, "header"

    def take(self, fmt: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        if self.offset + size > len(self.data):
            raise InputError(self.path, self.record,
                             f"cannot read COLMAP model: the file ends at byte {len(self.data)}, inside the record")
        values = struct.unpack_from("<" + fmt, self.data, self.offset)
        self.offset += size
        return values

    def skip(self, count: int, size: int, what: str) -> None:
        if count * size > len(self.data) - self.offset:
            raise InputError(self.path, self.record,
                             f"cannot read COLMAP model: {count} {what} do not fit in the "
                             f"{len(self.data) - self.offset} bytes left")
        self.offset += count * size

    def count(self, min_size: int, what: str) -> int:
        (n,) = self.take("Q")
        if n * min_size > len(self.data) - self.offset:
            raise InputError(self.path, "header", f"cannot read COLMAP model: {n} {what} do not fit in a "
                                                  f"file of {len(self.data)} bytes")
        return n

    def name(self) -> str:
        end = self.data.find(b"\0", self.offset)
        if end < 0:
            raise InputError(self.path, self.record, "cannot read COLMAP model: the image name is not terminated")
        raw = self.data[self.offset:end]
        self.offset = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError(self.path, self.record, "image name is not UTF-8") from None

    def done(self) -> None:
        if self.offset != len(self.data):
            raise InputError(self.path, None, f"cannot read COLMAP model: {len(self.data) - self.offset} "
                                              "bytes after the last record")


def _rigs_bin(data, path, model: _Model) -> None:
    r = _Reader(data, path)
    for i in range(r.count(8, "rigs")):
        r.record = f"rigs[{i}]"
        rig_id, n_sensors = r.take("II")
        if rig_id in model.rig_ids:
            raise InputError(path, r.record, f"duplicate rig id {rig_id}")
        model.rig_ids.add(rig_id)
        sensors = model.rig_sensors[rig_id] = set()
        if n_sensors > 0:
            ref = r.take("iI")
            _sensor_type(path, r.record, ref[0])
            sensors.add(ref)
        if max(n_sensors - 1, 0) * 9 > len(data) - r.offset:
            raise InputError(path, r.record, f"cannot read COLMAP model: {n_sensors} sensors do not fit in the file")
        for _ in range(max(n_sensors - 1, 0)):
            sensor_type, sensor_id, has_pose = r.take("iIB")
            _sensor_type(path, r.record, sensor_type)
            sensors.add((sensor_type, sensor_id))
            if has_pose:
                _pose(path, r.record, r.take("7d"))
    r.done()


def _cameras_bin(data, path, model: _Model) -> None:
    r = _Reader(data, path)
    models = camera_models()
    for i in range(r.count(24, "cameras")):
        r.record = f"cameras[{i}]"
        camera_id, model_id, width, height = r.take("IiQQ")
        if model_id not in models:
            raise InputError(path, r.record, f"unknown camera model {model_id}")
        params = r.take(f"{models[model_id][1]}d")
        r.record = f"camera {camera_id}"
        _camera(model, path, r.record, camera_id, model_id, width, height, params)
    r.done()


def _frames_bin(data, path, model: _Model) -> None:
    r = _Reader(data, path)
    model.frames = path
    for i in range(r.count(64, "frames")):
        r.record = f"frames[{i}]"
        _, rig_id = r.take("II")
        _pose(path, r.record, r.take("7d"))
        if model.rig_ids and rig_id not in model.rig_ids:
            raise InputError(path, r.record, f"rig {rig_id} is not in rigs")
        (n_data,) = r.take("I")
        if n_data * 16 > len(data) - r.offset:
            raise InputError(path, r.record, f"cannot read COLMAP model: {n_data} data ids do not fit in the file")
        data_ids = [r.take("iIQ") for _ in range(n_data)]
        for sensor_type, _, _ in data_ids:
            _sensor_type(path, r.record, sensor_type)
        _frame(model, path, r.record, rig_id, data_ids)
    r.done()


def _images_bin(data, path, model: _Model) -> None:
    r = _Reader(data, path)
    for i in range(r.count(73, "images")):
        r.record = f"images[{i}]"
        (image_id,) = r.take("I")
        pose = r.take("7d")
        (camera_id,) = r.take("I")
        name = r.name()
        r.record = f"image {image_id}"
        _image(model, path, r.record, image_id, pose, camera_id, name)
        (n_points,) = r.take("Q")
        r.skip(n_points, 24, "2D points")
        model.points2d[image_id] = n_points
    r.done()


def _points_bin(data, path, model: _Model) -> None:
    r = _Reader(data, path)
    for i in range(r.count(43, "3D points")):
        r.record = f"points3D[{i}]"
        values = r.take("Q3d3BdQ")
        _position(path, f"point {values[0]}", values[1:4])
        start = r.offset
        r.skip(values[-1], 8, "track elements")
        track = np.frombuffer(data, dtype="<u4", count=2 * values[-1], offset=start).reshape(-1, 2)
        _track(model, path, f"point {values[0]}", track)
    r.done()


def _track(model: _Model, path, where, track: np.ndarray) -> None:
    """A point's track ``(n, 2)`` of (IMAGE_ID, POINT2D_IDX): every image exists and every
    index is below that image's number of 2D points (pycolmap would stop in a C++ range check)."""
    for image_id, idx in track.tolist():
        count = model.points2d.get(image_id)
        if count is None:
            raise InputError(path, where, f"track: image {image_id} is not in images")
        if idx >= count:
            raise InputError(path, where, f"track: 2D point index {idx} of image {image_id} is out of range "
                                          f"(the image has {count} 2D points)")


_BINARY = {"rigs": _rigs_bin, "cameras": _cameras_bin, "frames": _frames_bin,
           "images": _images_bin, "points3D": _points_bin}


# --- text ----------------------------------------------------------------------------------

def _text(data: bytes, path: Path) -> str:
    """``data`` as UTF-8 text without NUL bytes, else an InputError naming ``path``."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise InputError(path, None, f"not UTF-8 text (byte {e.start})") from None
    if "\0" in text:
        raise InputError(path, None, "not a text file (contains NUL bytes)")
    return text


def _lines(data: bytes, path: Path):
    """``(line number, tokens)`` of the data lines (not empty, not comments) of a text file."""
    text = _text(data, path)
    for number, line in enumerate(text.split("\n"), start=1):
        line = line.strip()
        if line and not line.startswith("#"):
            yield number, line.split()


def _ints(tokens, path, where, low: int = 0, high: int = 2 ** 32) -> list[int]:
    try:
        values = [int(t) for t in tokens]
    except ValueError:
        raise InputError(path, where, f"expected integers, got {' '.join(tokens)[:60]!r}") from None
    if any(not low <= v < high for v in values):
        raise InputError(path, where, f"integer out of range in {' '.join(tokens)[:60]!r}")
    return values


def _floats(tokens, path, where) -> list[float]:
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        raise InputError(path, where, f"not a number in {' '.join(tokens)[:60]!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise InputError(path, where, "non-finite number")
    return values


def _sensor(token: str, path, where) -> None:
    if token not in SENSOR_TYPES:
        raise InputError(path, where, f"unknown sensor type {token!r} (expected CAMERA or IMU)")


def _rigs_txt(data, path, model: _Model) -> None:
    for number, tokens in _lines(data, path):
        where = f"line {number}"
        if len(tokens) < 2:
            raise InputError(path, where, "expected RIG_ID NUM_SENSORS …")
        rig_id, n_sensors = _ints(tokens[:2], path, where)
        expected, k = 2, 2
        sensors = set()
        if n_sensors > 0:
            expected += 2
            if len(tokens) >= 4:
                _sensor(tokens[2], path, where)
                sensors.add((SENSOR_TYPES[tokens[2]], *_ints(tokens[3:4], path, where)))
            k = 4
        for _ in range(max(n_sensors - 1, 0)):
            if len(tokens) < k + 3:
                raise InputError(path, where, f"{n_sensors} sensors announced, the line ends before them")
            _sensor(tokens[k], path, where)
            sensors.add((SENSOR_TYPES[tokens[k]], *_ints(tokens[k + 1:k + 2], path, where)))
            has_pose = tokens[k + 2] == "1"
            if has_pose:
                if len(tokens) < k + 10:
                    raise InputError(path, where, "the line ends inside a sensor pose")
                _pose(path, where, _floats(tokens[k + 3:k + 10], path, where))
            k += 10 if has_pose else 3
        expected = max(expected, k)
        if len(tokens) != expected:
            raise InputError(path, where, f"expected {expected} values, got {len(tokens)}")
        if rig_id in model.rig_ids:
            raise InputError(path, where, f"duplicate rig id {rig_id}")
        model.rig_ids.add(rig_id)
        model.rig_sensors[rig_id] = sensors


def _cameras_txt(data, path, model: _Model) -> None:
    names = {name: (model_id, n) for model_id, (name, n, _) in camera_models().items()}
    for number, tokens in _lines(data, path):
        where = f"line {number}"
        if len(tokens) < 4:
            raise InputError(path, where, f"expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS…, got {len(tokens)} values")
        if tokens[1] not in names:
            raise InputError(path, where, f"unknown camera model {tokens[1][:40]!r}")
        camera_id, = _ints(tokens[:1], path, where)
        width, height = _ints(tokens[2:4], path, where, -(2 ** 63), 2 ** 63)
        params = _floats(tokens[4:], path, where)
        _camera(model, path, where, camera_id, names[tokens[1]][0], width, height, params)


def _frames_txt(data, path, model: _Model) -> None:
    model.frames = path
    for number, tokens in _lines(data, path):
        where = f"line {number}"
        if len(tokens) < 10:
            raise InputError(path, where, f"expected FRAME_ID RIG_ID QW QX QY QZ TX TY TZ NUM_DATA_IDS …, "
                                          f"got {len(tokens)} values")
        _, rig_id = _ints(tokens[:2], path, where)
        _pose(path, where, _floats(tokens[2:9], path, where))
        n_data, = _ints(tokens[9:10], path, where)
        if len(tokens) != 10 + 3 * n_data:
            raise InputError(path, where, f"{n_data} data ids need {10 + 3 * n_data} values, got {len(tokens)}")
        data_ids = []
        for k in range(n_data):
            _sensor(tokens[10 + 3 * k], path, where)
            sensor_id, = _ints(tokens[11 + 3 * k:12 + 3 * k], path, where)
            data_id, = _ints(tokens[12 + 3 * k:13 + 3 * k], path, where, 0, 2 ** 64)
            data_ids.append((SENSOR_TYPES[tokens[10 + 3 * k]], sensor_id, data_id))
        if model.rig_ids and rig_id not in model.rig_ids:
            raise InputError(path, where, f"rig {rig_id} is not in rigs")
        _frame(model, path, where, rig_id, data_ids)


def _images_txt(data, path, model: _Model) -> None:
    lines = list(_lines_with_blanks(data, path))
    i = 0
    while i < len(lines):
        number, tokens = lines[i]
        if not tokens:
            i += 1
            continue
        where = f"line {number}"
        if len(tokens) != 10:
            raise InputError(path, where, "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME "
                                          f"(10 values, no spaces in NAME), got {len(tokens)}")
        image_id, = _ints(tokens[:1], path, where)
        pose = _floats(tokens[1:8], path, where)
        camera_id, = _ints(tokens[8:9], path, where)
        _image(model, path, where, image_id, pose, camera_id, tokens[9])
        model.points2d[image_id] = 0
        if i + 1 < len(lines):                       # the POINTS2D line, possibly empty
            number, points = lines[i + 1]
            if len(points) % 3:
                raise InputError(path, f"line {number}", f"expected X Y POINT3D_ID triples, got {len(points)} values")
            _floats(points, path, f"line {number}")
            model.points2d[image_id] = len(points) // 3
        i += 2


def _lines_with_blanks(data: bytes, path: Path):
    """Like :func:`_lines`, but an empty line after an image line is kept (as no tokens): it is
    that image's (empty) list of 2D points."""
    text = _text(data, path)
    raw = text.split("\n")
    number = 0
    while number < len(raw):
        line = raw[number].strip()
        number += 1
        if not line or line.startswith("#"):
            continue
        yield number, line.split()
        if number < len(raw):                        # the next line, whatever it holds
            yield number + 1, raw[number].strip().split()
            number += 1


def _points_txt(data, path, model: _Model) -> None:
    for number, tokens in _lines(data, path):
        where = f"line {number}"
        if len(tokens) < 8 or (len(tokens) - 8) % 2:
            raise InputError(path, where, "expected POINT3D_ID X Y Z R G B ERROR and (IMAGE_ID, POINT2D_IDX) "
                                          f"pairs, got {len(tokens)} values")
        _ints(tokens[:1], path, where, 0, 2 ** 63)
        _position(path, where, _floats(tokens[1:4], path, where))
        _ints(tokens[4:7], path, where, 0, 256)
        _floats(tokens[7:8], path, where)
        track = _ints(tokens[8:], path, where)
        _track(model, path, where, np.array(track, dtype=np.int64).reshape(-1, 2))


_TEXT = {"rigs": _rigs_txt, "cameras": _cameras_txt, "frames": _frames_txt,
         "images": _images_txt, "points3D": _points_txt}
