"""The scene directory contract: round trips and one-line errors for bad input."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mvm.errors import InputError
from mvm.io.colmap import read_colmap, write_colmap
from mvm.io.scene_dir import read_scene, write_scene
from mvm.sim.simulate import SimConfig, simulate

from helpers import random_cameras, standing_poses


@pytest.fixture
def scene(bank_poses):
    return simulate(SimConfig(people=3, frames=12, seed=4), bank_poses)[0]


@pytest.mark.parametrize("binary", [True, False])
def test_scene_round_trip(tmp_path, scene, binary):
    write_scene(tmp_path / "s", scene.cameras, scene.poses, binary=binary)
    back = read_scene(tmp_path / "s")
    order = np.argsort(back.cameras.names)
    assert back.cameras.names == scene.cameras.names
    assert np.allclose(back.cameras.R[order], scene.cameras.R, atol=1e-9)
    assert np.allclose(back.cameras.t[order], scene.cameras.t, atol=1e-9)
    assert np.allclose(back.poses.keypoints, scene.poses.keypoints, atol=1e-3)
    assert np.array_equal(back.poses.ids, scene.poses.ids)
    assert np.allclose(back.poses.appearance, scene.poses.appearance, atol=1e-4)


def test_distortion_is_undone(tmp_path):
    import pycolmap

    rng = np.random.default_rng(0)
    cams = random_cameras(rng, 2)
    rec = pycolmap.Reconstruction()
    K = cams.K[0]
    camera = pycolmap.Camera(model="OPENCV", width=1280, height=720,
                             params=[K[0, 0], K[1, 1], K[0, 2], K[1, 2], -0.2, 0.05, 0.001, -0.001], camera_id=1)
    rec.add_camera_with_trivial_rig(camera)
    for i in range(2):
        rec.add_image_with_trivial_frame(pycolmap.Image(name=cams.names[i], camera_id=1, image_id=i + 1),
                                         pycolmap.Rigid3d(pycolmap.Rotation3d(cams.R[i]), cams.t[i]))
    (tmp_path / "s" / "sparse").mkdir(parents=True)
    rec.write_text(str(tmp_path / "s" / "sparse"))
    X = standing_poses(1)[0] + 1.6 * cams.R[0][0]                               # towards the image edge
    cam_pts = X @ cams.R[0].T + cams.t[0]
    distorted = np.asarray(camera.img_from_cam(cam_pts))
    kp = np.concatenate([distorted, np.ones((17, 1))], 1)
    doc = {"images": [{"id": 1, "file_name": cams.names[0], "width": 1280, "height": 720}],
           "annotations": [{"id": 7, "image_id": 1, "category_id": 1, "keypoints": kp.reshape(-1).tolist(),
                            "score": 1}],
           "categories": []}
    (tmp_path / "s" / "poses2d.json").write_text(json.dumps(doc))
    back = read_scene(tmp_path / "s")
    pinhole = cam_pts[:, :2] / cam_pts[:, 2:] * K[0, 0] + K[:2, 2]
    assert np.abs(back.poses.keypoints[0, :, :2] - pinhole).max() < 1e-3
    assert np.abs(distorted - pinhole).max() > 5


def _write(tmp_path, scene, mutate=None, name="s"):
    path = tmp_path / name
    write_scene(path, scene.cameras, scene.poses)
    if mutate:
        doc = json.loads((path / "poses2d.json").read_text())
        mutate(doc)
        (path / "poses2d.json").write_text(json.dumps(doc))
    return path


def _nan(doc):
    doc["annotations"][2]["keypoints"][4] = math.nan


def _unknown_image(doc):
    doc["images"][0]["file_name"] = "not_in_model.jpg"


def _short(doc):
    doc["annotations"][1]["keypoints"] = doc["annotations"][1]["keypoints"][:34]


def _empty(doc):
    doc["annotations"] = []


def _string(doc):
    doc["annotations"][0]["keypoints"][0] = "12"


@pytest.mark.parametrize("mutate, expected", [
    (_nan, "poses2d.json: annotations[2].keypoints[4]: not a finite number (nan)"),
    (_unknown_image, "poses2d.json: images[0].file_name: image 'not_in_model.jpg' is not in the COLMAP model"),
    (_short, "poses2d.json: annotations[1].keypoints: expected 51 numbers (17 keypoints × x, y, v), got 34"),
    (_empty, "poses2d.json: annotations: no 2D poses in registered images: nothing to reconstruct"),
    (_string, "poses2d.json: annotations[0].keypoints[0]: expected a number, got str"),
])
def test_bad_poses2d_gives_one_line(tmp_path, scene, mutate, expected):
    path = _write(tmp_path, scene, mutate)
    with pytest.raises(InputError) as info:
        read_scene(path)
    message = str(info.value)
    assert "\n" not in message
    assert expected in message
    assert str(path) in message


def test_missing_sparse_and_missing_file(tmp_path, scene):
    path = _write(tmp_path, scene)
    import shutil

    shutil.rmtree(path / "sparse")
    with pytest.raises(InputError, match="sparse: missing COLMAP model directory"):
        read_scene(path)
    with pytest.raises(InputError, match="not a scene directory"):
        read_scene(tmp_path / "nowhere")


def test_corrupt_colmap_model(tmp_path, scene):
    path = _write(tmp_path, scene)
    (path / "sparse" / "images.bin").write_bytes(b"\x01\x02garbage")
    with pytest.raises(InputError, match="cannot read COLMAP model"):
        read_scene(path)


def test_colmap_mapper_layout_sparse_0(tmp_path, scene):
    write_colmap(tmp_path / "sparse" / "0", scene.cameras, binary=True)
    model = read_colmap(tmp_path / "sparse")
    assert model.cameras.names == scene.cameras.names


def test_reads_legacy_colmap_text_layout(tmp_path):
    """cameras.txt / images.txt / points3D.txt as COLMAP < 3.12 writes them (no rigs, frames)."""
    sparse = tmp_path / "sparse"
    sparse.mkdir()
    (sparse / "cameras.txt").write_text("# Camera list with one line of data per camera:\n"
                                        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
                                        "1 SIMPLE_RADIAL 640 480 500 320 240 0.01\n")
    (sparse / "images.txt").write_text("# Image list with two lines of data per image:\n"
                                       "1 1 0 0 0 0 0 0 1 a.jpg\n\n"
                                       "2 0.7071068 0 0.7071068 0 0.5 0 2 1 b.jpg\n\n")
    (sparse / "points3D.txt").write_text("# 3D point list\n1 0.5 0.2 3.0 255 0 0 0.5\n")
    model = read_colmap(sparse)
    assert model.cameras.names == ("a.jpg", "b.jpg")
    assert np.allclose(model.cameras.K[0], [[500, 0, 320], [0, 500, 240], [0, 0, 1]])
    # Quaternion (w, x, y, z) = 90° about y; centre C = -R^T t.
    assert np.allclose(model.cameras.R[1], [[0, 0, 1], [0, 1, 0], [-1, 0, 0]], atol=1e-6)
    assert np.allclose(model.cameras.centers[1], [2.0, 0.0, -0.5], atol=1e-6)
    assert np.allclose(model.points3d, [[0.5, 0.2, 3.0]])


@pytest.mark.parametrize("binary", [True, False])
def test_a_model_read_again_is_the_same_and_its_own(tmp_path, binary, monkeypatch):
    """Scenes of one rig share their model: the second is not parsed again, yet every read
    gives the model of its own files, arrays of its own, and a malformed copy is still refused."""
    import mvm.io.colmap as colmap

    monkeypatch.setattr(colmap, "_last", None)
    parsed, real = [], colmap._parse
    monkeypatch.setattr(colmap, "_parse",
                        lambda model_dir, *rest: parsed.append(model_dir.name) or real(model_dir, *rest))
    rng = np.random.default_rng(3)
    cams = random_cameras(rng, 4)
    for name in ("a", "b"):
        write_colmap(tmp_path / name, cams, binary=binary)
    first, second = read_colmap(tmp_path / "a"), read_colmap(tmp_path / "b")
    assert parsed == ["a"]
    assert second.cameras.names == cams.names
    assert np.allclose(second.cameras.t, cams.t, atol=1e-9)
    first.cameras.t[:] = 0.0                                  # a caller's edit stays its own
    assert np.allclose(read_colmap(tmp_path / "b").cameras.t, cams.t, atol=1e-9)

    moved = type(cams)(cams.K, cams.R, cams.t + 1.0, cams.size, cams.names)
    write_colmap(tmp_path / "c", moved, binary=binary)
    assert np.allclose(read_colmap(tmp_path / "c").cameras.t, moved.t, atol=1e-9)

    ext = "bin" if binary else "txt"
    for name in ("cameras", "images", "points3D"):
        (tmp_path / "d" / f"{name}.{ext}").parent.mkdir(exist_ok=True)
        (tmp_path / "d" / f"{name}.{ext}").write_bytes((tmp_path / "c" / f"{name}.{ext}").read_bytes())
    images = tmp_path / "d" / f"images.{ext}"
    images.write_bytes(images.read_bytes() + b"\n1 garbage\n")
    read_colmap(tmp_path / "c")
    with pytest.raises(InputError):
        read_colmap(tmp_path / "d")
    assert parsed == ["a", "c"]
