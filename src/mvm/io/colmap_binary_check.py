"""The binary files of a COLMAP model (``*.bin``, COLMAP's ``reconstruction_io_binary.cc``)
walked record by record, each count checked against the bytes that remain."""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.colmap_records import (
    ModelRecords,
    camera_models,
    check_camera,
    check_frame,
    check_image,
    check_pose,
    check_position,
    check_sensor_type,
    check_track,
)


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


def _rigs_bin(data, path, model: ModelRecords) -> None:
    r = _Reader(data, path)
    for i in range(r.count(8, "rigs")):
        r.record = f"rigs[{i}]"
        rig_id, n_sensors = r.take("II")
        if rig_id in model.rig_ids:
            raise InputError(path, r.record, f"duplicate rig id {rig_id}")
        model.rig_ids.add(rig_id)
        sensors = model.rig_sensors[rig_id] = set()
        model.one_camera_rigs &= n_sensors <= 1
        if n_sensors > 0:
            ref = r.take("iI")
            check_sensor_type(path, r.record, ref[0])
            sensors.add(ref)
        if max(n_sensors - 1, 0) * 9 > len(data) - r.offset:
            raise InputError(path, r.record, f"cannot read COLMAP model: {n_sensors} sensors do not fit in the file")
        for _ in range(max(n_sensors - 1, 0)):
            sensor_type, sensor_id, has_pose = r.take("iIB")
            check_sensor_type(path, r.record, sensor_type)
            sensors.add((sensor_type, sensor_id))
            if has_pose:
                check_pose(path, r.record, r.take("7d"))
    r.done()


def _cameras_bin(data, path, model: ModelRecords) -> None:
    r = _Reader(data, path)
    models = camera_models()
    for i in range(r.count(24, "cameras")):
        r.record = f"cameras[{i}]"
        camera_id, model_id, width, height = r.take("IiQQ")
        if model_id not in models:
            models = camera_models(model_id)
        if model_id not in models:
            raise InputError(path, r.record, f"unknown camera model {model_id}")
        params = r.take(f"{models[model_id][1]}d")
        r.record = f"camera {camera_id}"
        check_camera(model, path, r.record, camera_id, model_id, width, height, params)
    r.done()


def _frames_bin(data, path, model: ModelRecords) -> None:
    r = _Reader(data, path)
    model.frames = path
    for i in range(r.count(64, "frames")):
        r.record = f"frames[{i}]"
        _, rig_id = r.take("II")
        pose = r.take("7d")
        check_pose(path, r.record, pose)
        if model.rig_ids and rig_id not in model.rig_ids:
            raise InputError(path, r.record, f"rig {rig_id} is not in rigs")
        (n_data,) = r.take("I")
        if n_data * 16 > len(data) - r.offset:
            raise InputError(path, r.record, f"cannot read COLMAP model: {n_data} data ids do not fit in the file")
        data_ids = [r.take("iIQ") for _ in range(n_data)]
        for sensor_type, _, _ in data_ids:
            check_sensor_type(path, r.record, sensor_type)
        check_frame(model, path, r.record, rig_id, data_ids, pose)
    r.done()


def _images_bin(data, path, model: ModelRecords) -> None:
    r = _Reader(data, path)
    for i in range(r.count(73, "images")):
        r.record = f"images[{i}]"
        (image_id,) = r.take("I")
        pose = r.take("7d")
        (camera_id,) = r.take("I")
        name = r.name()
        r.record = f"image {image_id}"
        check_image(model, path, r.record, image_id, pose, camera_id, name)
        (n_points,) = r.take("Q")
        r.skip(n_points, 24, "2D points")
        model.points2d[image_id] = n_points
    r.done()


def _points_bin(data, path, model: ModelRecords) -> None:
    r = _Reader(data, path)
    for i in range(r.count(43, "3D points")):
        r.record = f"points3D[{i}]"
        values = r.take("Q3d3BdQ")
        check_position(path, f"point {values[0]}", values[1:4])
        model.points.append(values[1:4])
        start = r.offset
        r.skip(values[-1], 8, "track elements")
        track = np.frombuffer(data, dtype="<u4", count=2 * values[-1], offset=start).reshape(-1, 2)
        check_track(model, path, f"point {values[0]}", track)
    r.done()


BINARY_CHECKS = {"rigs": _rigs_bin, "cameras": _cameras_bin, "frames": _frames_bin,
           "images": _images_bin, "points3D": _points_bin}
