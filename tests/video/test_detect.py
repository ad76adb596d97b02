"""Importers of foreign 2D pose files (each written in its published layout), the poses2d.json
they produce, and one-line errors for bad files."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from mvm.errors import InputError
from mvm.io.coco import read_coco_keypoints
from mvm.io.coco_results import read_coco_results
from mvm.io.pose_format import pose_format
from mvm.video.detect import DetectOptions, detect_scene

#: COCO-17 joint -> BODY_25 index (BODY_25: 0 nose, 1 neck, 2-4 right arm, 5-7 left arm, 8 mid-hip,
#: 9-11 right leg, 12-14 left leg, 15/16 right/left eye, 17/18 right/left ear, 19-24 feet).
COCO_TO_BODY25 = [0, 16, 15, 18, 17, 5, 2, 6, 3, 7, 4, 12, 9, 13, 10, 14, 11]
NAMES = [f"frame_{k:05d}.jpg" for k in (0, 3, 6)]


@pytest.fixture
def scene(tmp_path):
    """A scene with 3 frames (no camera model) and 2 true poses per frame."""
    rng = np.random.default_rng(0)
    (tmp_path / "frames").mkdir()
    for name in NAMES:
        cv2.imwrite(str(tmp_path / "frames" / name), rng.integers(0, 255, (120, 160, 3), dtype=np.uint8))
    kp = np.zeros((len(NAMES), 2, 17, 3))
    kp[..., 0] = rng.uniform(10, 150, (len(NAMES), 2, 17))
    kp[..., 1] = rng.uniform(10, 110, (len(NAMES), 2, 17))
    kp[..., 2] = rng.uniform(0.5, 1.0, (len(NAMES), 2, 17))
    kp[:, 1, 4] = 0.0                    # a missing joint
    return tmp_path, kp.round(2)


def _check(scene_dir, kp, appearance=True):
    coco = read_coco_keypoints(scene_dir / "poses2d.json")
    assert coco.file_names == tuple(NAMES)
    assert len(coco.keypoints) == kp.shape[0] * kp.shape[1]
    got = coco.keypoints[np.lexsort((coco.keypoints[:, 0, 0], coco.ann_image))]
    want = kp[np.arange(3)[:, None], np.argsort(kp[:, :, 0, 0], axis=1)].reshape(-1, 17, 3)
    assert np.allclose(got, want, atol=1e-3)
    assert (coco.appearance is not None) == appearance


def test_openpifpaf_directory(scene, tmp_path_factory):
    scene_dir, kp = scene
    source = tmp_path_factory.mktemp("pifpaf")
    for f, name in enumerate(NAMES):
        preds = [{"keypoints": kp[f, p].reshape(-1).tolist(), "bbox": [0, 0, 10, 10], "score": 0.8,
                  "category_id": 1} for p in range(2)]
        (source / f"{name}.predictions.json").write_text(json.dumps(preds))
    assert pose_format(source)[0] == "openpifpaf"
    detect_scene(scene_dir, source)
    _check(scene_dir, kp)


def test_openpose_body25_directory(scene, tmp_path_factory):
    scene_dir, kp = scene
    source = tmp_path_factory.mktemp("openpose")
    for f, name in enumerate(NAMES):
        people = []
        for p in range(2):
            body = np.zeros((25, 3))
            body[COCO_TO_BODY25] = kp[f, p]
            body[1] = [5, 5, 0.9]        # neck, not a COCO joint
            people.append({"person_id": [-1], "pose_keypoints_2d": body.reshape(-1).tolist(),
                           "face_keypoints_2d": [], "hand_left_keypoints_2d": [], "hand_right_keypoints_2d": []})
        (source / f"{name[:-4]}_keypoints.json").write_text(json.dumps({"version": 1.3, "people": people}))
    assert pose_format(source)[0] == "openpose"
    detect_scene(scene_dir, source, options=DetectOptions(appearance="none"))
    _check(scene_dir, kp, appearance=False)


def test_coco_results_by_name_and_by_position(scene, tmp_path):
    scene_dir, kp = scene
    results = []
    for f, name in enumerate(NAMES):
        for p in range(2):
            image_id = name if p == 0 else f + 1          # file name, or 1-based position
            results.append({"image_id": image_id, "category_id": 1, "keypoints": kp[f, p].reshape(-1).tolist(),
                            "score": 0.7})
    results.append({"image_id": "not_a_frame.jpg", "category_id": 1, "keypoints": [0] * 51, "score": 0.5})
    path = tmp_path / "results.json"
    path.write_text(json.dumps(results))
    assert pose_format(path)[0] == "coco-results"
    detect_scene(scene_dir, path)
    _check(scene_dir, kp)
    # done work is skipped unless forced
    before = (scene_dir / "poses2d.json").stat().st_mtime_ns
    detect_scene(scene_dir, path)
    assert (scene_dir / "poses2d.json").stat().st_mtime_ns == before


@pytest.mark.parametrize("content, field", [
    ("{not json", "not valid JSON"),
    (json.dumps([{"image_id": NAMES[0], "keypoints": [1, 2, 3]}]), "[0].keypoints"),
    (json.dumps([{"image_id": 1.5, "keypoints": [0] * 51}]), "[0].image_id"),
])
def test_bad_coco_results_name_the_file(tmp_path, content, field):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(InputError) as info:
        read_coco_results(path)
    message = str(info.value)
    assert str(path) in message and field in message and "\n" not in message


def test_bad_openpose_file_is_one_line_exit_2(scene, tmp_path_factory):
    from mvm.cli.video import detect_cmd

    scene_dir, _ = scene
    source = tmp_path_factory.mktemp("bad_openpose")
    bad = source / "frame_00000_keypoints.json"
    bad.write_text(json.dumps({"people": [{"pose_keypoints_2d": [1, 2, 3, 4]}]}))
    result = CliRunner().invoke(detect_cmd, [str(scene_dir), "--import", str(source)])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and str(bad) in lines[0] and "pose_keypoints_2d" in lines[0]


def _tiny_checkpoint(path):
    torch = pytest.importorskip("torch", reason="torch is an optional dependency")
    try:
        from mvm.net.checkpoints import CHECKPOINT_FORMAT
        from mvm.net.model import ModelSpec, PoseNet
    except ImportError as e:
        pytest.skip(f"the pose network is not available: {e}")
    torch.manual_seed(0)
    model = PoseNet(ModelSpec("resnet18", 16, 8))
    torch.save({"model": model.state_dict()}, path)
    path.with_suffix(".json").write_text(json.dumps({"format": CHECKPOINT_FORMAT, "model": model.spec.to_dict()}))
    return model


def test_network_checkpoint_detects_and_pools_features(scene, tmp_path_factory, monkeypatch):
    pytest.importorskip("mvm.net.predict", reason="mvm.net.predict is not available")
    import mvm.net.evaluate as evaluate

    scene_dir, kp = scene
    checkpoint = tmp_path_factory.mktemp("net") / "checkpoint-0000001.pt"
    _tiny_checkpoint(checkpoint)
    # an untrained network finds nobody: make the decoder return the true poses of the frame
    calls = iter(range(len(NAMES)))
    real = evaluate.run_model

    def run_model(model, image, input_size, decoder=None):
        poses, fields, scale = real(model, image, input_size)
        f = next(calls)
        return type(poses)(kp[f], np.zeros((2, 17)), np.array([0.9, 0.8])), fields, scale

    monkeypatch.setattr(evaluate, "run_model", run_model)
    d = detect_scene(scene_dir, checkpoint=checkpoint, options=DetectOptions(input_size=161))
    assert d.source.startswith("mvm:")
    assert d.appearance is not None and d.appearance.shape == (6, 8 * 8)   # resnet18 width 8: 64 channels
    assert np.allclose(np.linalg.norm(d.appearance, axis=1), 1)
    _check(scene_dir, kp)
