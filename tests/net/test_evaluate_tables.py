"""The `mvm evaluate` commands (Tables 3 and 4; Table 5 in tests/eval/test_cvar.py), and the export of a
rendered simulation."""
import json

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.main import main
from mvm.core.scene import Persons3D
from mvm.sim.simulate import SimConfig, simulate


def test_evaluate_commands_have_help_and_reject_bad_input(tmp_path):
    runner = CliRunner()
    for sub in ("3dpw", "coco", "cvar"):
        assert runner.invoke(main, ["evaluate", sub, "--help"]).exit_code == 0
    (tmp_path / "gt.json").write_text(json.dumps({"images": [], "annotations": []}))
    bad = runner.invoke(main, ["evaluate", "coco", str(tmp_path / "gt.json"),
                               "--detections", str(tmp_path / "nope.json")])
    assert bad.exit_code == 2 and "nope.json" in bad.output and bad.output.count("\n") == 1
    bad = runner.invoke(main, ["evaluate", "3dpw", str(tmp_path), "--checkpoint", str(tmp_path / "x.pt")])
    assert bad.exit_code == 2 and "x.pt: file not found" in bad.output and bad.output.count("\n") == 1
    (tmp_path / "x.pt").write_bytes(b"")
    bad = runner.invoke(main, ["evaluate", "3dpw", str(tmp_path), "--checkpoint", str(tmp_path / "x.pt")])
    assert bad.exit_code == 2 and "sequenceFiles" in bad.output and bad.output.count("\n") == 1


def test_evaluate_coco_prints_the_table_row(tmp_path):
    kp = np.zeros((17, 3))
    kp[:, 0], kp[:, 1], kp[:, 2] = np.linspace(100, 200, 17), np.linspace(50, 300, 17), 2
    gt = {"images": [{"id": 1, "file_name": "a.jpg", "width": 400, "height": 400}],
          "annotations": [{"id": 1, "image_id": 1, "category_id": 1, "keypoints": kp.reshape(-1).tolist()}],
          "categories": [{"id": 1, "name": "person"}]}
    (tmp_path / "gt.json").write_text(json.dumps(gt))
    (tmp_path / "dt.json").write_text(json.dumps([{"image_id": 1, "keypoints": kp.reshape(-1).tolist(), "score": 0.9}]))
    result = CliRunner().invoke(main, ["evaluate", "coco", str(tmp_path / "gt.json"), "--detections",
                                       str(tmp_path / "dt.json"), "--out", str(tmp_path / "t4.json")])
    assert result.exit_code == 0, result.output
    assert "mAP@OKS" in result.output and "100.0" in result.output
    assert json.loads((tmp_path / "t4.json").read_text())["AP"] == pytest.approx(1.0)


def test_rendered_simulation_exports_and_trains(tmp_path):
    """simulate -> render frames -> export (true grouping) -> one training step on the frames."""
    from mvm.net.checkpoints import read_checkpoint
    from mvm.net.supervision import export_supervision
    from mvm.net.train import train
    from mvm.net.train_config import DataSource, TrainConfig
    from mvm.sim.mannequin_video import render_frames

    scene, truth = simulate(SimConfig.preset("clean", people=2, frames=4, seed=3, image_width=640, image_height=360))
    frames = render_frames(tmp_path / "frames", scene.cameras, truth.poses3d, seed=3)
    assert [f.name for f in frames] == list(scene.cameras.names)
    import cv2

    image = cv2.imread(str(frames[0]))
    assert image.shape == (360, 640, 3) and image.std() > 10                    # a textured room, not a blank
    P = len(truth.poses3d)
    persons = Persons3D(truth.poses3d, np.ones((P, 17)), [scene.poses.ids[truth.person == p] for p in range(P)],
                        np.full((P, 17), 3, int), np.zeros((P, 17), int), np.zeros(P))
    data = export_supervision([(scene, persons, tmp_path / "frames")], tmp_path / "ds", link="symlink")
    doc = json.loads(data.read_text())
    assert len(doc["images"]) == 4 and sum(a["num_keypoints"] > 0 for a in doc["annotations"]) >= 4
    cfg = TrainConfig(train=(DataSource(str(data)),), backbone="resnet18", stride=16, width=8, input_size=64,
                      batch_size=2, steps=1, out_dir=str(tmp_path / "run"), device="cpu", threads=1)
    _, meta = read_checkpoint(train(cfg))
    assert meta["step"] == 1 and meta["losses"]["L_PDF"] > 0                      # depth supervision reached the loss


@pytest.mark.parametrize("tau", ["nan", "-0.1", "1.5", "inf"])
def test_c_var_refuses_a_tau_outside_0_1(tmp_path, tau):
    result = CliRunner().invoke(main, ["evaluate", "cvar", str(tmp_path), "--tau", tau])
    assert result.exit_code == 2 and "--tau: expected a confidence threshold in [0, 1]" in result.output
    assert result.output.count("\n") == 1


@pytest.mark.parametrize("change, field", [({"keypoints": [float("nan")] + [1.0] * 50}, r"\[0\].keypoints\[0\]"),
                                           ({"score": float("inf")}, r"\[0\].score"),
                                           ({"image_id": "1"}, r"\[0\].image_id"),
                                           ({"keypoints": [1.0] * 34}, r"\[0\].keypoints: expected 51")])
def test_evaluate_coco_refuses_a_detection_that_is_not_finite_numbers(tmp_path, change, field):
    import re

    kp = np.zeros((17, 3))
    kp[:, 0], kp[:, 1], kp[:, 2] = np.linspace(100, 200, 17), np.linspace(50, 300, 17), 2
    gt = {"images": [{"id": 1, "file_name": "a.jpg", "width": 400, "height": 400}],
          "annotations": [{"id": 1, "image_id": 1, "category_id": 1, "keypoints": kp.reshape(-1).tolist()}],
          "categories": [{"id": 1, "name": "person"}]}
    (tmp_path / "gt.json").write_text(json.dumps(gt))
    detection = {"image_id": 1, "keypoints": kp.reshape(-1).tolist(), "score": 0.9, **change}
    (tmp_path / "dt.json").write_text(json.dumps([detection]))
    result = CliRunner().invoke(main, ["evaluate", "coco", str(tmp_path / "gt.json"), "--detections",
                                       str(tmp_path / "dt.json")])
    assert result.exit_code == 2 and result.output.count("\n") == 1, result.output
    assert re.search(rf"dt\.json: {field}", result.output), result.output
