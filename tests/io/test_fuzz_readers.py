"""Property-based fuzzing of every reader: mutated valid files give a valid object or one
``InputError`` line, never another exception.

Each reader starts from valid files made by the project's writers (or in the format's
published layout) and hypothesis mutates them: values dropped, retyped, NaN, huge or
negative, lists cut or lengthened, ids duplicated, text tokens replaced, added or dropped,
files truncated, bad UTF-8 and NUL bytes, binary COLMAP counts, ids, camera models, image
sizes and quaternions overwritten. Three readers of binary files get their own mutations: 3DPW
pickles (fields retyped, strings and huge ids in arrays, other protocols, calls of functions
that must never run), model zips (names that climb out of the cache, absolute names, links,
devices, lying sizes, many members) and images (truncated, flipped, empty). A model zip must
never write outside its cache folder. ``benchmarks/fuzz_readers.py`` runs the same cases at
scale (>= 10,000) and prints the counts.
"""
from __future__ import annotations

import copy
import dataclasses
import io
import json
import math
import pickle
import shutil
import stat
import struct
import tempfile
import traceback
import warnings
import zipfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from mvm.errors import InputError
from mvm.io.paths import name_problem

from helpers import random_cameras, standing_poses

WEIRD = [None, True, False, 0, -1, 1, 2, 3, 7, 2 ** 31, 2 ** 63, 10 ** 30, 10 ** 400, -1e308, 1e308, 0.5, -0.0,
         math.nan, math.inf, -math.inf, "", "x", "1.5", "../../etc/passwd", "/abs/x.jpg", "a\\..\\..\\b",
         [], [1, 2], [[1, 2, 3]], {}, {"a": 1}, [math.nan] * 51, list(range(75)), "é" * 3]
TOKENS = ["nan", "inf", "-inf", "-1", "0", "1", "2", "3", "1e400", "-1e308", "99999999999999999999",
          "4294967295", "x", "#", "FOO_MODEL", "SIMPLE_RADIAL", "OPENCV", "EQUIRECTANGULAR", "CAMERA",
          "IMU", "../a.jpg", "/abs.jpg", "1.5", "\t", "=", "[", '"', "\\"]
SPECIAL_U32 = [0, 1, 2, 3, 17, 99, 2 ** 31, 2 ** 32 - 1]
SPECIAL_U64 = [0, 1, 2, 4, 2 ** 31, 2 ** 32, 2 ** 63, 2 ** 64 - 1]
SPECIAL_F64 = [0.0, -1.0, 1e308, math.nan, math.inf, -math.inf, 5e-324]


# --- valid files, made by the project's writers ------------------------------------------------

def _cameras(V: int = 3):
    return random_cameras(np.random.default_rng(0), V)


def _projected_keypoints(cameras, V: int):
    """``(V, 17, 3)`` keypoints of one standing person seen by each camera."""
    X = standing_poses(1)[0]
    cam = np.einsum("vij,nj->vni", cameras.R, X) + cameras.t[:, None]
    xy = cam[..., :2] / cam[..., 2:] * cameras.K[:, None, 0, 0][..., None] + cameras.K[:, None, :2, 2]
    return np.concatenate([xy, np.full((V, 17, 1), 0.9)], axis=2)


@dataclass
class Seeds:
    """Valid files per reader: ``{reader: {relative path: bytes}}``."""

    files: dict = field(default_factory=dict)


def _read_dir(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def make_seeds() -> dict[str, dict[str, bytes]]:
    from mvm.core.scene import Poses2D
    from mvm.io.calib_toml import RigCalibration, calib_toml_text
    from mvm.io.coco import coco_keypoints_document
    from mvm.io.colmap import write_colmap
    from mvm.io.scene_dir import write_scene
    from mvm.io.trc import trc_text

    V = 3
    cams = _cameras(V)
    kp = _projected_keypoints(cams, V)
    seeds: dict[str, dict[str, bytes]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_colmap(tmp / "bin", cams, binary=True, points3d=standing_poses(1)[0][:4])
        write_colmap(tmp / "txt", cams, binary=False, points3d=standing_poses(1)[0][:4])
        seeds["colmap_bin"] = {f"sparse/{k}": v for k, v in _read_dir(tmp / "bin").items()}
        seeds["colmap_txt"] = {f"sparse/{k}": v for k, v in _read_dir(tmp / "txt").items()}
        poses = Poses2D(kp, np.arange(V), np.arange(1, V + 1), np.full(V, 0.9), np.eye(V, 4))
        write_scene(tmp / "scene", cams, poses, binary=False)
        seeds["scene"] = _read_dir(tmp / "scene")
    coco = coco_keypoints_document(cams.names, cams.size, np.arange(V), kp, np.full(V, 0.9),
                                   appearance=np.eye(V, 4))
    seeds["coco"] = {"poses2d.json": json.dumps(coco).encode()}
    body25 = np.zeros((25, 3))
    body25[[0, 16, 15, 18, 17, 5, 2, 6, 3, 7, 4, 12, 9, 13, 10, 14, 11]] = kp[0]
    seeds["openpose"] = {"cam1_000012_keypoints.json": json.dumps(
        {"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": body25.reshape(-1).tolist(),
                                     "face_keypoints_2d": []},
                                    {"person_id": [-1], "pose_keypoints_2d": kp[1].reshape(-1).tolist()}]}).encode()}
    seeds["openpifpaf"] = {"000012.predictions.json": json.dumps(
        [{"keypoints": kp[v].reshape(-1).tolist(), "bbox": [1.0, 2.0, 30.0, 80.0], "score": 0.8, "category_id": 1}
         for v in range(2)]).encode()}
    calib = RigCalibration(dataclasses.replace(
        cams, distortion=(np.array([-0.1, 0.01, 0.0, 0.0]), np.zeros(5), np.array([0.01, 0.0, 0.0, 0.0])),
        fisheye=np.array([False, False, True])))
    seeds["calib_toml"] = {"Calib.toml": calib_toml_text(calib).encode()}
    lines = ["https://www.youtube.com/watch?v=abcdefghijk"]
    for f in range(3):
        Rt = np.concatenate([cams.R[f], cams.t[f][:, None]], axis=1)
        values = [1000 * (f + 1), 0.8, 1.4, 0.5, 0.5, 0, 0] + Rt.reshape(-1).tolist()
        lines.append(" ".join(f"{v:.9g}" for v in values))
    seeds["trajectory"] = {"cameras.txt": ("\n".join(lines) + "\n").encode()}
    seeds["panoptic_calib"] = {"calibration.json": json.dumps({"calibCameras": 1, "cameras": [
        {"name": f"00_{v:02d}", "type": "hd", "resolution": [1920, 1080], "panel": 0, "node": v,
         "K": cams.K[v].tolist(), "distCoef": [-0.2, 0.1, 0.0, 0.0, 0.0], "R": cams.R[v].tolist(),
         "t": (100 * cams.t[v])[:, None].tolist()} for v in range(V)]}).encode()}
    points = standing_poses(4)[:, :5]
    points[1, 2] = np.nan
    seeds["trc"] = {"person.trc": trc_text(points, [f"m{i}" for i in range(5)], 30.0).encode()}
    from mvm.core.scene import Persons3D
    from mvm.io.scene_dir import poses3d_document

    X = standing_poses(2)
    X[0, 3] = np.nan
    persons = Persons3D(X, np.full((2, 17), 0.8), [np.array([0, 1]), np.array([2])], np.full((2, 17), 3),
                        np.zeros((2, 17), int), np.array([1.5, np.nan]))
    seeds["poses3d"] = {"poses3d.json": json.dumps(poses3d_document(persons, poses, {"persons": 2})).encode()}
    seeds["config"] = {"config.toml": b"[reconstruct]\ntau = 0.25\nrefine = false\nmin_views = 3\n"
                                      b"ransac_threshold = 0.08\nseed = 4\n"}
    # a reconstructed scene: what `mvm report` and the batch statistics read
    seeds["report"] = {**seeds["scene"], "mvm/poses3d.json": seeds["poses3d"]["poses3d.json"]}
    seeds["batch"] = dict(seeds["report"])
    seeds["rig"] = _rig_seeds()
    seeds["status"] = _status_seeds(seeds["report"])
    seeds["threedpw"] = {"sequenceFiles/test/clip.pkl": pickle.dumps(threedpw_doc(), protocol=2)}
    seeds["model_zip"] = {"m.zip": model_zip([("20231211/rtmo-s/end2end.onnx", b"onnx bytes " * 50),
                                              ("20231211/deploy.json", b"{}")])}
    seeds["image"] = {"frames/a.jpg": _image_bytes(".jpg"), "frames/b.png": _image_bytes(".png")}
    return seeds


def threedpw_doc(frames: int = 3, people: int = 2) -> dict:
    """A 3DPW sequence dict of the published layout (its numbers arbitrary but finite)."""
    rng = np.random.default_rng(0)
    cam = np.tile(np.eye(4), (frames, 1, 1))
    cam[:, 2, 3] = 5.0
    return {"sequence": "clip", "img_frame_ids": np.arange(frames), "cam_poses": cam,
            "cam_intrinsics": np.array([[1000.0, 0, 540], [0, 1000.0, 960], [0, 0, 1]]),
            "jointPositions": [rng.normal(size=(frames, 72)) for _ in range(people)],
            "poses2d": [rng.uniform(0, 1, size=(frames, 3, 18)) for _ in range(people)],
            "campose_valid": [np.ones(frames, bool) for _ in range(people)],
            "betas": [np.zeros(10, np.float32)] * people, "genders": ["m", "f"][:people]}


def model_zip(members) -> bytes:
    """A zip of ``members``: (name or ZipInfo, data)."""
    buffer = io.BytesIO()
    with warnings.catch_warnings(), zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as z:
        warnings.simplefilter("ignore", UserWarning)                  # duplicate names are a case too
        for name, data in members:
            z.writestr(name, data)
    return buffer.getvalue()


def _image_bytes(ext: str) -> bytes:
    import cv2

    image = np.zeros((12, 16, 3), np.uint8)
    image[3:8, 4:12] = (40, 200, 90)
    return cv2.imencode(ext, image)[1].tobytes()


def _status_seeds(scene: dict[str, bytes]) -> dict[str, bytes]:
    """A batch root: one reconstructed clip and the manifest that records it as done."""
    import tempfile

    from mvm.batch.clips import Clip
    from mvm.batch.manifest import MANIFEST, Manifest
    from mvm.batch.stages import StageResult

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        manifest = Manifest(root)
        manifest.register([Clip("a", "a", str(root / "a"))], ["reconstruct"])
        run = manifest.begin_run("local", 1, ["reconstruct"])
        assert manifest.claim(run, "a", "reconstruct")
        manifest.commit(run, StageResult("a", "reconstruct", True, 1.5, checksum="0" * 64, files=1,
                                         stats={"persons": 2, "E_R_px": 1.5}))
        manifest.end_run(run, "done")
        manifest.db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        manifest.close()
        files = {MANIFEST.as_posix(): (root / MANIFEST).read_bytes()}
    return {**files, **{f"a/{rel}": data for rel, data in scene.items()}}


def _rig_seeds() -> dict[str, bytes]:
    """A rig directory: Calib.toml of two cameras and one COCO pose file per camera."""
    from mvm.io.calib_toml import RigCalibration, calib_toml_text
    from mvm.io.coco import coco_keypoints_document

    names = ("cam_1", "cam_2")
    cams = random_cameras(np.random.default_rng(1), 2)
    cams = type(cams)(cams.K, cams.R, cams.t, cams.size, names)
    kp = _projected_keypoints(cams, 2)
    files = {"Calib.toml":
             calib_toml_text(RigCalibration(dataclasses.replace(cams, distortion=(np.zeros(4), np.zeros(4))))).encode()}
    for v, name in enumerate(names):
        doc = coco_keypoints_document([f"{name}_000001.jpg", f"{name}_000002.jpg"], np.repeat(cams.size[v:v + 1], 2, 0),
                                      np.array([0, 1]), np.stack([kp[v], kp[v]]), np.full(2, 0.9))
        files[f"pose/{name}.json"] = json.dumps(doc).encode()
    return files


# --- the readers and what a returned object must satisfy ---------------------------------------

def _finite(*arrays) -> None:
    for a in arrays:
        assert np.isfinite(np.asarray(a, dtype=float)).all(), "a returned array is not finite"


def _check_cameras(cameras) -> None:
    _finite(cameras.K, cameras.R, cameras.t, cameras.size)
    assert np.allclose(np.einsum("vij,vkj->vik", cameras.R, cameras.R), np.eye(3), atol=1e-6)
    assert all(name_problem(n) is None for n in cameras.names)


def _coco(root: Path):
    from mvm.io.coco import read_coco_keypoints

    c = read_coco_keypoints(root / "poses2d.json")
    _finite(c.keypoints, c.score, c.sizes)
    assert (c.keypoints.shape == (len(c.ann_ids), 17, 3)
            and ((c.keypoints[..., 2] >= 0) & (c.keypoints[..., 2] <= 1)).all())
    assert ((c.ann_image >= 0) & (c.ann_image < len(c.file_names))).all()
    assert all(name_problem(n) is None for n in c.file_names)
    if c.appearance is not None:
        _finite(c.appearance)


def _colmap(root: Path):
    from mvm.io.colmap import read_colmap

    model = read_colmap(root / "sparse")
    _check_cameras(model.cameras)
    _finite(model.points3d)


def _scene(root: Path):
    from mvm.io.scene_dir import read_scene

    scene = read_scene(root)
    _check_cameras(scene.cameras)
    _finite(scene.poses.keypoints, scene.poses.score)
    assert ((scene.poses.view >= 0) & (scene.poses.view < len(scene.cameras))).all()


def _openpose(root: Path):
    from mvm.io.openpose import read_openpose_frame

    kp = read_openpose_frame(root / "cam1_000012_keypoints.json")
    assert kp.ndim == 3 and kp.shape[1:] == (17, 3)
    _finite(kp)


def _openpifpaf(root: Path):
    from mvm.io.openpifpaf import read_openpifpaf_frame

    kp, score = read_openpifpaf_frame(root / "000012.predictions.json")
    assert kp.shape == (len(score), 17, 3)
    _finite(kp, score)


def _calib(root: Path):
    from mvm.io.calib_toml import read_calib_toml

    calib = read_calib_toml(root / "Calib.toml")
    _check_cameras(calib.cameras)
    assert (calib.cameras.size > 0).all()
    _finite(*calib.distortions)


def _trajectory(root: Path):
    from mvm.io.trajectory import read_trajectory

    t = read_trajectory(root / "cameras.txt")
    assert len(t) >= 2
    _finite(t.timestamps_us, t.intrinsics, t.R, t.t, t.centers)


def _panoptic(root: Path):
    from mvm.io.panoptic_calib import read_panoptic_calibration

    calib = read_panoptic_calibration(root / "calibration.json")
    _check_cameras(calib.cameras)
    _finite(*calib.distortions)


def _trc(root: Path):
    from mvm.io.trc import read_trc

    trc = read_trc(root / "person.trc")
    assert not np.isinf(trc.points).any()
    _finite(trc.times, trc.frames, [trc.rate])
    assert trc.points.shape == (len(trc.frames), len(trc.markers), 3)


def _poses3d(root: Path):
    from mvm.io.scene_dir import read_poses3d

    persons = read_poses3d(root / "poses3d.json")
    assert not np.isinf(persons.keypoints3d).any()
    _finite(persons.scores)
    assert (np.isnan(persons.keypoints3d).all(axis=2) | np.isfinite(persons.keypoints3d).all(axis=2)).all()


def _config(root: Path):
    from mvm.core.config import Config
    from mvm.settings.tables import load_config

    config = load_config(root / "config.toml")
    assert isinstance(config, Config)
    assert all(math.isfinite(v) for v in vars(config).values() if isinstance(v, float))


def _report(root: Path):
    from mvm.report.analysis import reproject
    from mvm.report.load import load_result

    result = load_result(root)
    _check_cameras(result.scene.cameras)
    assert not np.isinf(result.persons.keypoints3d).any()
    uv, ok = reproject(result.persons.keypoints3d, result.scene.cameras.P)
    assert not np.isinf(uv[ok]).any()
    assert all(v is None or isinstance(v, str) or np.isfinite(np.asarray(v, dtype=float)).all()
               for v in result.metrics.values() if not isinstance(v, dict))


def _batch(root: Path):
    from mvm.batch.stages import clip_stats

    stats = clip_stats(root)
    assert stats["frames"] >= 1 and stats["poses2d"] >= 0
    for value in stats.values():
        assert value is None or isinstance(value, str) or np.isfinite(np.asarray(value, dtype=float)).all()


def _status(root: Path):
    from mvm.batch.status import batch_status

    status = batch_status(root, verify=True)
    json.dumps(status.to_json(), allow_nan=False)


def _rig(root: Path):
    from mvm.rig.rigdir import read_rig

    rig = read_rig(root)
    _check_cameras(rig.calibration.cameras)
    assert (rig.frames >= 0).all() and (rig.frames <= 10 ** 9).all()
    _finite(rig.detections.keypoints[..., :2][rig.detections.keypoints[..., 2] > 0])


def _threedpw(root: Path):
    from mvm.net.threedpw import read_3dpw

    blob = (root / "sequenceFiles" / "test" / "clip.pkl").read_bytes()
    hostile = any(f"c{module}\n{name}\n".encode() in blob for module, name, _ in HOSTILE_GLOBALS)
    RAN.unlink(missing_ok=True)
    try:
        data = read_3dpw(root)
    except InputError as e:
        if hostile and blob.startswith(b"\x80\x02c"):           # the call is the first thing read
            assert "refusing to load" in str(e), f"a pickle naming a function was not refused by type: {e}"
        raise
    finally:
        assert not RAN.exists(), "a function named by a pickle ran"
    assert not hostile, "a pickle naming a function was read"
    _finite(data.joints3d, data.joints2d, data.intrinsics)
    assert data.joints3d.shape == (len(data), 14, 3) and len(data.images) == len(data)
    assert all(root in p.parents for p in data.images)


def _model_zip(root: Path):
    from mvm.video.models import onnx_in_zip

    cache = root / "cache"
    before = {p: p.read_bytes() for p in root.rglob("*") if p.is_file()}
    try:
        onnx = onnx_in_zip(root / "m.zip", cache / "m")
        assert onnx.suffix.lower() == ".onnx" and cache / "m" in onnx.resolve().parents and onnx.is_file()
    finally:
        after = {p for p in root.rglob("*") if p.is_file() or p.is_symlink()}
        outside = {p for p in after if cache not in p.parents}
        assert outside == set(before), (
            f"written or removed outside the cache: {sorted(map(str, outside ^ set(before)))}")
        assert all(p.read_bytes() == before[p] for p in outside), "a file outside the cache changed"
        assert not [p for p in after if ".part" in p.name], "a temporary file was left in the cache"


def _image(root: Path):
    from mvm.io.images import read_image

    for name in ("frames/a.jpg", "frames/b.png"):
        image = read_image(root / name, root=root)
        assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3 and image.size > 0


READERS = {"coco": _coco, "colmap_bin": _colmap, "colmap_txt": _colmap, "scene": _scene,
           "openpose": _openpose, "openpifpaf": _openpifpaf, "calib_toml": _calib,
           "trajectory": _trajectory, "panoptic_calib": _panoptic, "trc": _trc, "config": _config,
           "poses3d": _poses3d, "report": _report, "batch": _batch, "rig": _rig, "status": _status,
           "threedpw": _threedpw, "model_zip": _model_zip, "image": _image}


# --- mutations ----------------------------------------------------------------------------------

def _json_paths(doc, prefix=()):
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _json_paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:4]):
            yield from _json_paths(v, prefix + (i,))
        if len(doc) > 4:
            yield from _json_paths(doc[-1], prefix + (len(doc) - 1,))


def _get(doc, path):
    for key in path:
        doc = doc[key]
    return doc


@st.composite
def mutate_json(draw, data: bytes) -> bytes:
    doc = json.loads(data)
    for _ in range(draw(st.integers(1, 3))):
        paths = list(_json_paths(doc))
        path = draw(st.sampled_from(paths))
        op = draw(st.sampled_from(["replace", "replace", "delete", "truncate", "duplicate", "extend"]))
        value = copy.deepcopy(draw(st.sampled_from(WEIRD)))
        if not path:
            doc = value if op == "replace" else doc
            continue
        parent, key = _get(doc, path[:-1]), path[-1]
        target = parent[key]
        if op == "replace":
            parent[key] = value
        elif op == "delete":
            del parent[key]
        elif op == "truncate" and isinstance(target, list):
            parent[key] = target[:draw(st.integers(0, max(len(target) - 1, 0)))]
        elif op == "duplicate" and isinstance(target, list) and target:
            target.append(json.loads(json.dumps(target[draw(st.integers(0, len(target) - 1))])))
        elif op == "extend" and isinstance(target, list):
            target.append(value)
        else:
            parent[key] = value
    return json.dumps(doc).encode()


@st.composite
def mutate_text(draw, data: bytes) -> bytes:
    lines = data.decode().split("\n")
    for _ in range(draw(st.integers(1, 3))):
        k = draw(st.integers(0, len(lines) - 1))
        sep = "\t" if "\t" in lines[k] else " "
        parts = lines[k].split(sep)
        op = draw(st.sampled_from(["token", "token", "drop", "add", "delete_line", "duplicate_line", "cut"]))
        token = draw(st.sampled_from(TOKENS))
        i = draw(st.integers(0, len(parts) - 1))
        if op == "token":
            parts[i] = token
        elif op == "drop":
            del parts[i]
        elif op == "add":
            parts.insert(i, token)
        if op == "delete_line" and len(lines) > 1:
            del lines[k]
        elif op == "duplicate_line":
            lines.insert(k, lines[k])
        elif op == "cut":
            lines = lines[:k]
        else:
            lines[k] = sep.join(parts)
        if not lines:
            lines = [""]
    return "\n".join(lines).encode()


@st.composite
def mutate_bytes(draw, data: bytes) -> bytes:
    data = bytearray(data)
    op = draw(st.sampled_from(["truncate", "truncate", "flip", "flip", "bad_utf8", "nul", "long_int", "deep"]))
    k = draw(st.integers(0, max(len(data) - 1, 0)))
    if op == "truncate":
        return bytes(data[:k])
    if op == "flip" and data:
        data[k] = draw(st.integers(0, 255))
    elif op == "long_int":
        data[k:k] = b"1" * 5000
    elif op == "deep":
        data[k:k] = b"[" * 20000 + b"]" * 20000
    elif op == "bad_utf8":
        data[k:k] = draw(st.sampled_from([b"\xff", b"\xc3", b"\xed\xa0\x80", b"\xfe\xff"]))
    else:
        data[k:k] = b"\0"
    return bytes(data)


@st.composite
def mutate_colmap_bin(draw, data: bytes) -> bytes:
    data = bytearray(data)
    fmt, values = draw(st.sampled_from([("I", SPECIAL_U32), ("i", [-1, 5, 17, 18, 99, -7]),
                                        ("Q", SPECIAL_U64), ("d", SPECIAL_F64)]))
    size = struct.calcsize("<" + fmt)
    if len(data) < size:
        return bytes(data)
    offset = draw(st.one_of(st.sampled_from([0, 8, 12, 16, 24, 32, 44, 68]),
                            st.integers(0, len(data) - size)))
    offset = min(offset, len(data) - size)
    struct.pack_into("<" + fmt, data, offset, draw(st.sampled_from(values)))
    return bytes(data)


#: Structured mutations at the fields of the first record of write_colmap's binary files.
BIN_FIELDS = [("cameras.bin", 0, "Q", SPECIAL_U64), ("cameras.bin", 12, "i", [-1, 5, 17, 18, 99]),
              ("cameras.bin", 16, "Q", [0, 2 ** 40, 2 ** 63]), ("cameras.bin", 24, "Q", [0, 2 ** 63]),
              ("cameras.bin", 32, "d", SPECIAL_F64), ("cameras.bin", 8, "I", [2, 7]),
              ("images.bin", 0, "Q", SPECIAL_U64), ("images.bin", 8, "I", [2, 3, 77]),
              ("images.bin", 12, "4d", [(0.0, 0.0, 0.0, 0.0), (math.nan, 0.0, 0.0, 0.0), (1e-200, 0, 0, 0)]),
              ("images.bin", 44, "d", SPECIAL_F64), ("images.bin", 68, "I", [0, 2, 9]),
              ("frames.bin", 0, "Q", SPECIAL_U64), ("frames.bin", 16, "4d", [(0.0, 0.0, 0.0, 0.0)]),
              ("frames.bin", 12, "I", [7]), ("frames.bin", 72, "I", [2 ** 32 - 1, 0, 2]),
              ("rigs.bin", 0, "Q", SPECIAL_U64), ("rigs.bin", 12, "I", SPECIAL_U32),
              ("points3D.bin", 0, "Q", SPECIAL_U64), ("points3D.bin", 16, "d", SPECIAL_F64)]


@st.composite
def mutate_colmap_field(draw, files: dict) -> dict:
    name, offset, fmt, values = draw(st.sampled_from(BIN_FIELDS))
    key = f"sparse/{name}"
    data = bytearray(files[key])
    value = draw(st.sampled_from(values))
    struct.pack_into("<" + fmt, data, offset, *(value if isinstance(value, tuple) else (value,)))
    return {**files, key: bytes(data)}


NAMES = ["../../outside.jpg", "/etc/passwd", "a/../../b.jpg", "C:\\x.jpg", "..", "sub/../f0001.jpg",
         "sub/ok.jpg", "f0000.jpg", "é.jpg"]


@st.composite
def mutate_scene_names(draw, files: dict) -> dict:
    """Rename image 0 in poses2d.json and/or in the COLMAP model."""
    name = draw(st.sampled_from(NAMES))
    files = dict(files)
    where = draw(st.sampled_from(["coco", "colmap", "both"]))
    if where in ("coco", "both"):
        doc = json.loads(files["poses2d.json"])
        doc["images"][0]["file_name"] = name
        files["poses2d.json"] = json.dumps(doc).encode()
    if where in ("colmap", "both"):
        files["sparse/images.txt"] = files["sparse/images.txt"].replace(b" f0000.jpg", b" " + name.encode())
    return files


#: The file a hostile pickle's call creates if it ever runs.
RAN = Path(tempfile.gettempdir()) / "mvm-fuzz-pickle-ran"
_TOUCH = f"__import__('pathlib').Path({str(RAN)!r}).touch()"
#: Functions a hostile pickle calls, with the argument that makes the call leave :data:`RAN`
#: where it can (the others must be refused by their type all the same).
HOSTILE_GLOBALS = [("os", "system", f"touch {RAN}"), ("posix", "system", f"touch {RAN}"),
                   ("subprocess", "getoutput", f"touch {RAN}"), ("builtins", "eval", _TOUCH),
                   ("builtins", "exec", _TOUCH), ("__builtin__", "eval", _TOUCH), ("builtins", "getattr", "x"),
                   ("numpy", "load", str(RAN)), ("copyreg", "_reconstructor", "x"), ("builtins", "__import__", "os"),
                   ("numpy", "frombuffer", "x"), ("_codecs", "decode", "x"), ("numpy.core.multiarray", "x", "x")]
PICKLE_VALUES = WEIRD + [np.array(["a", "b", "c"]), np.array([0, 1, 10 ** 18]), np.array([1, "x"], dtype=object),
                         np.full((3, 72), np.nan), np.zeros((3, 4, 4), np.float16), np.zeros((0, 72)),
                         np.zeros(3, complex), np.array([-1, 0, 1]), "../../../etc", np.float64(2.5), np.int8(3),
                         np.zeros((3, 3, 18)), {"nested": [np.zeros(2)]}, (1, 2), {1, 2}, b"bytes"]


def _hostile_pickle(module: str, name: str, argument: str, wrap: bool) -> bytes:
    """A protocol-2 pickle that calls ``module.name(argument)``: alone, or as the value of one
    more key of a valid sequence dict (the call hidden among good fields)."""
    text = argument.encode()
    call = f"c{module}\n{name}\n".encode() + b"X" + struct.pack("<I", len(text)) + text + b"\x85R"
    if not wrap:
        return b"\x80\x02" + call + b"."
    body = pickle.dumps(threedpw_doc(), protocol=2)            # ... SETITEMS STOP: the dict on the stack
    return body[:-1] + b"X\x05\x00\x00\x00extra" + call + b"s."


@st.composite
def mutate_pickle(draw, data: bytes) -> bytes:
    op = draw(st.sampled_from(["field", "field", "field", "drop", "protocol", "hostile", "hostile", "top"]))
    doc = threedpw_doc(frames=draw(st.integers(1, 4)), people=draw(st.integers(0, 2)))
    protocol = draw(st.sampled_from([0, 1, 2, 3, 4, 5]))
    if op == "hostile":
        return _hostile_pickle(*draw(st.sampled_from(HOSTILE_GLOBALS)), wrap=draw(st.booleans()))
    if op == "top":
        return pickle.dumps(draw(st.sampled_from(PICKLE_VALUES)), protocol=protocol)
    for _ in range(draw(st.integers(1, 2))):
        key = draw(st.sampled_from(sorted(doc)))
        if op == "drop":
            doc.pop(key, None)
        elif op == "field":
            value = draw(st.sampled_from(PICKLE_VALUES))
            if isinstance(doc[key], list) and doc[key] and draw(st.booleans()):
                doc[key][draw(st.integers(0, len(doc[key]) - 1))] = value
            else:
                doc[key] = value
    return pickle.dumps(doc, protocol=protocol)


#: Zip member names that must never be unpacked where they point.
ZIP_NAMES = ["../victim.onnx", "a/../../../victim_up.onnx", "/tmp/abs.onnx", "C:/x.onnx", "..\\x.onnx",
             "sub/../model.onnx", "ok/model.onnx", "model.ONNX", "x.onnx/", "", "a\x00b.onnx", "é.onnx", "m.zip"]
ZIP_MODES = [0, stat.S_IFREG | 0o644, stat.S_IFLNK | 0o777, stat.S_IFCHR | 0o666, stat.S_IFBLK | 0o666,
             stat.S_IFIFO | 0o666, stat.S_IFSOCK | 0o666, stat.S_IFDIR | 0o755]


@st.composite
def mutate_zip(draw, data: bytes) -> bytes:
    op = draw(st.sampled_from(["names", "names", "mode", "many", "sizes", "empty"]))
    members = [(zipfile.ZipInfo("20231211/rtmo-s/end2end.onnx"), b"onnx bytes " * 50)]
    if op == "names":
        for _ in range(draw(st.integers(1, 3))):
            members.append((zipfile.ZipInfo(draw(st.sampled_from(ZIP_NAMES))), b"evil"))
        if draw(st.booleans()):
            members = members[1:]
    elif op == "mode":
        info = zipfile.ZipInfo(draw(st.sampled_from(["model.onnx", "link", "dev/x.onnx"])))
        info.external_attr = draw(st.sampled_from(ZIP_MODES)) << 16
        members.insert(draw(st.integers(0, 1)), (info, b"/etc/passwd"))
    elif op == "many":
        members += [(zipfile.ZipInfo(f"f{i}"), b"") for i in range(draw(st.sampled_from([10, 1001, 1500])))]
    elif op == "empty":
        members = []
    buffer = model_zip(members)
    if op == "sizes":                          # the declared size of the model, central directory and local header
        data = bytearray(buffer)
        size = draw(st.sampled_from([0, 1, 549, 551, 2 ** 32 - 1]))
        for header, offset in ((b"PK\x01\x02", 24), (b"PK\x03\x04", 22)):
            if draw(st.booleans()) and header in data:
                at = data.index(header) + offset
                data[at:at + 4] = size.to_bytes(4, "little")
        buffer = bytes(data)
    return buffer


@st.composite
def cases(draw, reader: str, seeds: dict) -> dict:
    """Mutated files for ``reader``: ``{relative path: bytes}``."""
    files = dict(seeds[reader])
    if reader == "scene" and draw(st.booleans()):
        files = draw(mutate_scene_names(files))
        if draw(st.booleans()):
            return files
    if reader == "colmap_bin" and draw(st.booleans()):
        return draw(mutate_colmap_field(files))
    manifest = ".mvm/manifest.sqlite"
    key = manifest if manifest in files and draw(st.booleans()) else draw(st.sampled_from(sorted(files)))
    data = files[key]
    layer = draw(st.sampled_from(["structure", "structure", "structure", "bytes"]))
    if layer == "bytes" or key.endswith((".jpg", ".png")):
        files[key] = draw(mutate_bytes(data))
    elif key.endswith(".pkl"):
        files[key] = draw(mutate_pickle(data))
    elif key.endswith(".zip"):
        files[key] = draw(mutate_zip(data))
    elif key.endswith(".json"):
        files[key] = draw(mutate_json(data))
    elif key.endswith(".bin"):
        files[key] = draw(mutate_colmap_bin(data))
    elif key.endswith(".sqlite"):
        files[key] = draw(mutate_bytes(data))
    else:
        files[key] = draw(mutate_text(data))
    if draw(st.integers(0, 9)) == 0:
        files[key] = draw(mutate_bytes(files[key]))
    return files


# --- running one case ---------------------------------------------------------------------------

@dataclass
class Tally:
    """Outcomes per reader: ``counts[reader][outcome]``; ``crashes`` maps a description of each
    distinct uncaught exception to an example of the files that caused it."""

    counts: dict = field(default_factory=dict)
    crashes: dict = field(default_factory=dict)

    def add(self, reader: str, outcome: str) -> None:
        self.counts.setdefault(reader, Counter())[outcome] += 1


def run_case(reader: str, files: dict, root: Path, tally: Tally | None = None, strict: bool = True) -> str:
    """Write ``files`` under ``root`` (emptied first), run ``reader`` and return the outcome:
    ``"valid"`` or ``"input_error"``. Anything else is a crash: raised when ``strict``, else
    recorded in ``tally`` and returned as ``"crash"``."""
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(parents=True)
    for rel, data in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(data)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            READERS[reader](root)
        outcome = "valid"
    except InputError as e:
        line = str(e)
        if "\n" in line or not line.startswith(str(root)):
            outcome = "crash"
            error = AssertionError(f"InputError is not one line naming a file under the input: {line[:200]!r}")
        else:
            outcome = "input_error"
    except Exception as e:  # noqa: BLE001 - everything else is what we hunt
        outcome, error = "crash", e
    if tally is not None:
        tally.add(reader, outcome)
    if outcome == "crash":
        frame = traceback.extract_tb(error.__traceback__)[-1]
        where = f"{Path(frame.filename).name}:{frame.lineno}"
        message = str(error).splitlines()[0][:120] if str(error) else frame.line
        key = f"{reader}: {type(error).__name__} at {where}"
        if tally is not None and key not in tally.crashes:
            tally.crashes[key] = (message, files)
        if strict:
            raise AssertionError(f"{key}: {message}") from error
    return outcome


# --- the test -----------------------------------------------------------------------------------

_SEEDS: dict = {}


def seeds() -> dict:
    if not _SEEDS:
        _SEEDS.update(make_seeds())
    return _SEEDS


def test_seeds_are_valid(tmp_path):
    """The unmutated files read back: the fuzzing starts from valid input."""
    for reader, files in seeds().items():
        assert run_case(reader, files, tmp_path / reader) == "valid", reader


@pytest.mark.parametrize("reader", sorted(READERS))
def test_fuzz_reader(reader, tmp_path_factory):
    root = tmp_path_factory.mktemp(f"fuzz_{reader}") / "case"
    tally = Tally()

    @settings(max_examples=150, derandomize=True, deadline=None, database=None,
              phases=[Phase.explicit, Phase.generate, Phase.shrink],
              suppress_health_check=list(HealthCheck))
    @given(st.data())
    def check(data):
        run_case(reader, data.draw(cases(reader, seeds())), root, tally)

    check()
    counts = tally.counts[reader]
    assert counts["crash"] == 0
    assert counts["input_error"] > 0, "the mutations never produced a bad file"
