"""The text files of a COLMAP model (``*.txt``, COLMAP's ``reconstruction_io_text.cc``)
walked line by line, each count checked against the tokens that remain."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io import colmap_records as records


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
    if token not in records.SENSOR_TYPES:
        raise InputError(path, where, f"unknown sensor type {token!r} (expected CAMERA or IMU)")


def _rigs_txt(data, path, model: records.ModelRecords) -> None:
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
                sensors.add((records.SENSOR_TYPES[tokens[2]], *_ints(tokens[3:4], path, where)))
            k = 4
        for _ in range(max(n_sensors - 1, 0)):
            if len(tokens) < k + 3:
                raise InputError(path, where, f"{n_sensors} sensors announced, the line ends before them")
            _sensor(tokens[k], path, where)
            sensors.add((records.SENSOR_TYPES[tokens[k]], *_ints(tokens[k + 1:k + 2], path, where)))
            has_pose = tokens[k + 2] == "1"
            if has_pose:
                if len(tokens) < k + 10:
                    raise InputError(path, where, "the line ends inside a sensor pose")
                records.check_pose(path, where, _floats(tokens[k + 3:k + 10], path, where))
            k += 10 if has_pose else 3
        expected = max(expected, k)
        if len(tokens) != expected:
            raise InputError(path, where, f"expected {expected} values, got {len(tokens)}")
        if rig_id in model.rig_ids:
            raise InputError(path, where, f"duplicate rig id {rig_id}")
        model.rig_ids.add(rig_id)
        model.rig_sensors[rig_id] = sensors
        model.one_camera_rigs &= n_sensors <= 1


def _cameras_txt(data, path, model: records.ModelRecords) -> None:
    names = {name: (model_id, n) for model_id, (name, n, _) in records.camera_models().items()}
    for number, tokens in _lines(data, path):
        where = f"line {number}"
        if len(tokens) < 4:
            raise InputError(path, where, f"expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS…, got {len(tokens)} values")
        if tokens[1] not in names:
            names = {name: (model_id, n) for model_id, (name, n, _) in records.camera_models(tokens[1]).items()}
        if tokens[1] not in names:
            raise InputError(path, where, f"unknown camera model {tokens[1][:40]!r}")
        camera_id, = _ints(tokens[:1], path, where)
        width, height = _ints(tokens[2:4], path, where, -(2 ** 63), 2 ** 63)
        params = _floats(tokens[4:], path, where)
        records.check_camera(model, path, where, camera_id, names[tokens[1]][0], width, height, params)


def _frames_txt(data, path, model: records.ModelRecords) -> None:
    model.frames = path
    for number, tokens in _lines(data, path):
        where = f"line {number}"
        if len(tokens) < 10:
            raise InputError(path, where, f"expected FRAME_ID RIG_ID QW QX QY QZ TX TY TZ NUM_DATA_IDS …, "
                                          f"got {len(tokens)} values")
        _, rig_id = _ints(tokens[:2], path, where)
        pose = _floats(tokens[2:9], path, where)
        records.check_pose(path, where, pose)
        n_data, = _ints(tokens[9:10], path, where)
        if len(tokens) != 10 + 3 * n_data:
            raise InputError(path, where, f"{n_data} data ids need {10 + 3 * n_data} values, got {len(tokens)}")
        data_ids = []
        for k in range(n_data):
            _sensor(tokens[10 + 3 * k], path, where)
            sensor_id, = _ints(tokens[11 + 3 * k:12 + 3 * k], path, where)
            data_id, = _ints(tokens[12 + 3 * k:13 + 3 * k], path, where, 0, 2 ** 64)
            data_ids.append((records.SENSOR_TYPES[tokens[10 + 3 * k]], sensor_id, data_id))
        if model.rig_ids and rig_id not in model.rig_ids:
            raise InputError(path, where, f"rig {rig_id} is not in rigs")
        records.check_frame(model, path, where, rig_id, data_ids, pose)


def _images_txt(data, path, model: records.ModelRecords) -> None:
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
        records.check_image(model, path, where, image_id, pose, camera_id, tokens[9])
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


def _points_txt(data, path, model: records.ModelRecords) -> None:
    for number, tokens in _lines(data, path):
        where = f"line {number}"
        if len(tokens) < 8 or (len(tokens) - 8) % 2:
            raise InputError(path, where, "expected POINT3D_ID X Y Z R G B ERROR and (IMAGE_ID, POINT2D_IDX) "
                                          f"pairs, got {len(tokens)} values")
        _ints(tokens[:1], path, where, 0, 2 ** 63)
        xyz = _floats(tokens[1:4], path, where)
        records.check_position(path, where, xyz)
        model.points.append(xyz)
        _ints(tokens[4:7], path, where, 0, 256)
        _floats(tokens[7:8], path, where)
        track = _ints(tokens[8:], path, where)
        records.check_track(model, path, where, np.array(track, dtype=np.int64).reshape(-1, 2))


TEXT_CHECKS = {"rigs": _rigs_txt, "cameras": _cameras_txt, "frames": _frames_txt,
         "images": _images_txt, "points3D": _points_txt}
