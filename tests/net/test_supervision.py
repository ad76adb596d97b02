"""Supervision export: 3D poses projected into every frame, written as a mergeable COCO file."""
import json
import os

import numpy as np
import pytest
import torch

from mvm.core.camera import project_persons
from mvm.core.scene import Cameras, Persons3D, Poses2D, Scene
from mvm.errors import InputError
from mvm.net.data import read_annotations
from mvm.net.supervision import export_supervision, merge_datasets


def _scene(name, n_views=3, size=(160, 120)):
    K = np.tile(np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]]), (n_views, 1, 1))
    R = np.tile(np.eye(3), (n_views, 1, 1))
    t = np.array([[0.2 * v, 0, 0] for v in range(n_views)], dtype=float)
    cams = Cameras(K, R, t, np.tile(size, (n_views, 1)), tuple(f"f{v:03d}.png" for v in range(n_views)))
    poses = Poses2D(np.zeros((0, 17, 3)), np.zeros(0), np.zeros(0), np.zeros(0))
    return Scene(name, cams, poses)


def _persons():
    rng = np.random.default_rng(0)
    X = np.stack([rng.normal(scale=0.3, size=(17, 3)) + [0, 0, 4.0],
                  rng.normal(scale=0.3, size=(17, 3)) + [0.5, 0, 6.0]])
    X[0, 3] = np.nan                 # not reconstructed
    X[1, 4] = [0.0, 0.0, -1.0]       # behind every camera
    X[1, 5] = [50.0, 0.0, 6.0]       # outside every image
    P = len(X)
    return Persons3D(X, np.ones((P, 17)), [np.zeros(0, int)] * P, np.full((P, 17), 3), np.zeros((P, 17)), np.zeros(P))


def _frames(dir, scene):
    import cv2
    dir.mkdir(parents=True, exist_ok=True)
    for name in scene.cameras.names:
        cv2.imwrite(str(dir / name), np.zeros((120, 160, 3), np.uint8))
    return dir


def test_project_persons_labels_and_relative_depth():
    persons = _persons()
    K = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])
    kp, dep = project_persons(persons.keypoints3d, K, np.eye(3), np.zeros(3), (160, 120))
    X = persons.keypoints3d
    assert kp[0, 3, 2] == 0 and dep[0, 3] == 0
    assert kp[1, 4, 2] == 0 and kp[1, 5, 2] == 0
    ok = kp[..., 2] > 0
    np.testing.assert_allclose(kp[0, 0, :2], K[:2, :2] @ (X[0, 0, :2] / X[0, 0, 2]) + K[:2, 2])
    z_all = X[..., 2][ok]
    for p in range(2):                     # one reference per image: the people's depth order is kept
        np.testing.assert_allclose(dep[p, ok[p]], X[p, ok[p], 2] / np.median(z_all))
    assert np.median(dep[ok]) == pytest.approx(1.0)
    _, per_person = project_persons(persons.keypoints3d, K, np.eye(3), np.zeros(3), (160, 120), reference="person")
    for p in range(2):
        z = X[p, ok[p], 2]
        np.testing.assert_allclose(per_person[p, ok[p]], z / np.median(z))


@pytest.mark.parametrize("link", ["symlink", "copy", "none"])
def test_export_writes_a_coco_dataset(tmp_path, link):
    s1, s2 = _scene("room"), _scene("room", n_views=2)   # same name: kept apart
    f1, f2 = _frames(tmp_path / "a", s1), _frames(tmp_path / "b", s2)
    out = tmp_path / "out"
    path = export_supervision([(s1, _persons(), f1), (s2, _persons(), f2)], out, link=link)
    data = json.loads(path.read_text())
    assert len(data["images"]) == 5 and len({im["id"] for im in data["images"]}) == 5
    assert {im["scene"] for im in data["images"]} == {"room", "room_1"}
    assert len(data["annotations"]) == 10 and len({a["id"] for a in data["annotations"]}) == 10
    ann = data["annotations"][0]
    assert len(ann["keypoints"]) == 51 and len(ann["keypoint_depths"]) == 17 and len(ann["has_3d"]) == 17
    assert ann["keypoints"][3 * 3 + 2] == 0 and ann["keypoint_depths"][3] == 0 and ann["has_3d"][3] == 0
    for im in data["images"]:
        assert (out / im["file_name"]).is_file()
        if link == "symlink":
            assert os.path.islink(out / im["file_name"])
    parsed = read_annotations(path)
    assert np.isfinite(parsed.depths[0][0]).sum() == 16  # joint 3 of person 0 was not reconstructed


def test_export_and_merge_many_scenes(tmp_path):
    a = export_supervision([(_scene("s1"), _persons(), _frames(tmp_path / "f1", _scene("s1")))], tmp_path / "d1",
                           "copy")
    b = export_supervision([(_scene("s2"), _persons(), _frames(tmp_path / "f2", _scene("s2")))], tmp_path / "d2",
                           "copy")
    merged = merge_datasets([a, b], tmp_path / "all" / "train.json")
    data = json.loads(merged.read_text())
    assert len(data["images"]) == 6 and len({im["id"] for im in data["images"]}) == 6
    assert len({a["id"] for a in data["annotations"]}) == len(data["annotations"]) == 12
    for im in data["images"]:
        assert (merged.parent / im["file_name"]).is_file()
    ids = {im["id"] for im in data["images"]}
    assert all(a["image_id"] in ids for a in data["annotations"])


def test_export_bad_inputs(tmp_path):
    with pytest.raises(InputError, match="link"):
        export_supervision([], tmp_path, link="hardlink")
    with pytest.raises(InputError, match="frames_dir"):
        export_supervision([(_scene("s"), _persons())], tmp_path / "o", link="copy")
    with pytest.raises(InputError, match="frame not found"):
        export_supervision([(_scene("s"), _persons(), tmp_path / "missing")], tmp_path / "o", link="copy")
    with pytest.raises(InputError, match="expected"):
        export_supervision([("scene", "persons")], tmp_path / "o")


def test_unreconstructed_people_are_ignored_not_background(tmp_path):
    from mvm.net.data import AugmentConfig, KeypointDataset

    scene = _scene("s", n_views=2)
    kp = np.zeros((3, 17, 3))
    kp[:, :, 0], kp[:, :, 1], kp[:, :, 2] = np.linspace(100, 140, 17), np.linspace(20, 100, 17), 0.9
    # annotation 7 is held by person 0; 8 (view 0) and 9 (view 1) were not reconstructed
    poses = Poses2D(kp, np.array([0, 0, 1]), np.array([7, 8, 9]), np.ones(3))
    scene = Scene("s", scene.cameras, poses)
    persons = _persons()
    persons = Persons3D(persons.keypoints3d, persons.scores, [np.array([7]), np.zeros(0, int)],
                        persons.views_per_joint, persons.outliers_per_joint, persons.reprojection_error_px)
    path = export_supervision([(scene, persons, _frames(tmp_path / "f", scene))], tmp_path / "d", "copy")
    data = json.loads(path.read_text())
    ignored = [a for a in data["annotations"] if a["num_keypoints"] == 0]
    assert [a["image_id"] for a in ignored] == [1, 2]
    x, y, w, h = ignored[0]["bbox"]
    assert x < 100 and x + w > 140 and y < 20 and y + h > 100
    parsed = read_annotations(path)
    assert [len(b) for b in parsed.ignore] == [1, 1] and [len(k) for k in parsed.keypoints] == [2, 2]
    augment = AugmentConfig(input_size=120, crop_min=1.0, flip=0.0)
    item = KeypointDataset(parsed, 8, augment).sample(0, 0)
    without = KeypointDataset(parsed.__class__(**{**parsed.__dict__, "ignore": ()}), 8, augment).sample(0, 0)
    ignored_cells = torch.isnan(item["pif"][:, 0]).all(0).sum() - torch.isnan(without["pif"][:, 0]).all(0).sum()
    assert ignored_cells >= 20                         # the unreconstructed person's box: about 6 x 13 cells
