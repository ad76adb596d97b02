"""The paper's Table 5 (C_var on reconstructed scenes) and the `mvm evaluate` commands."""
import json

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.main import main
from mvm.core.scene import Persons3D
from mvm.errors import InputError
from mvm.io.scene_dir import poses3d_document, write_poses3d
from mvm.net.evaluate import evaluate_cvar
from mvm.sim.simulate import SimConfig, simulate, write_simulation


def _scene_with_true_groups(root, preset, seed=0):
    """A simulated scene whose poses3d.json groups every 2D pose into its true person."""
    scene, truth = simulate(SimConfig.preset(preset, people=3, frames=12, seed=seed))
    path = root / preset
    write_simulation(path, scene, truth)
    P = len(truth.poses3d)
    members = [np.nonzero(truth.person == p)[0] for p in range(P)]
    persons = Persons3D(truth.poses3d, np.ones((P, 17)), members, np.full((P, 17), 3, int),
                        np.zeros((P, 17), int), np.zeros(P))
    (path / "mvm").mkdir()
    write_poses3d(path / "mvm" / "poses3d.json", poses3d_document(persons, scene.poses, {}))
    return path


def test_c_var_of_exact_detections_is_zero_and_grows_with_detector_noise(tmp_path):
    clean, noisy = _scene_with_true_groups(tmp_path, "clean"), _scene_with_true_groups(tmp_path, "realistic")
    exact = evaluate_cvar([clean], taus=(0.5,))
    assert exact["C_var"]["0.5"] == pytest.approx(0.0, abs=1e-8)
    rough = evaluate_cvar([noisy], taus=(0.5, 0.9))
    assert rough["C_var"]["0.5"] > 1e-5 and set(rough["scenes"]) == {"realistic"}
    both = evaluate_cvar([clean, noisy], taus=(0.5,))
    assert both["C_var"]["0.5"] == pytest.approx((exact["C_var"]["0.5"] + rough["C_var"]["0.5"]) / 2)

    out = tmp_path / "table5.json"
    result = CliRunner().invoke(main, ["evaluate", "cvar", str(clean), str(noisy), "--tau", "0.5", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "C_var@tau=0.5" in result.output and json.loads(out.read_text())["C_var"]["0.5"] == pytest.approx(both["C_var"]["0.5"])
    missing = CliRunner().invoke(main, ["evaluate", "cvar", str(tmp_path / "nowhere")])
    assert isinstance(missing.exception, InputError) and "poses3d.json" in str(missing.exception)


def test_evaluate_commands_have_help_and_reject_bad_input(tmp_path):
    runner = CliRunner()
    for sub in ("3dpw", "coco", "cvar"):
        assert runner.invoke(main, ["evaluate", sub, "--help"]).exit_code == 0
    (tmp_path / "gt.json").write_text(json.dumps({"images": [], "annotations": []}))
    bad = runner.invoke(main, ["evaluate", "coco", str(tmp_path / "gt.json"), "--detections", str(tmp_path / "nope.json")])
    assert isinstance(bad.exception, InputError) and "nope.json" in str(bad.exception)
    bad = runner.invoke(main, ["evaluate", "3dpw", str(tmp_path), "--checkpoint", str(tmp_path / "x.pt")])
    assert isinstance(bad.exception, InputError) and "sequenceFiles" in str(bad.exception)


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
