"""The paper's Table 5: C_var of reconstructed scenes (``mvm evaluate cvar``), torch not needed."""
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.main import main
from mvm.core.scene import Persons3D
from mvm.eval.cvar import evaluate_cvar
from mvm.io.ground_truth import write_simulation
from mvm.io.scene_dir import poses3d_document, write_poses3d
from mvm.sim.simulate import SimConfig, simulate

from helpers import REPO


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
    assert ("C_var@tau=0.5" in result.output
            and json.loads(out.read_text())["C_var"]["0.5"] == pytest.approx(both["C_var"]["0.5"]))
    missing = CliRunner().invoke(main, ["evaluate", "cvar", str(tmp_path / "nowhere")])
    assert missing.exit_code == 2 and "poses3d.json" in missing.output and missing.output.count("\n") == 1


def test_c_var_runs_without_torch(tmp_path):
    """The evaluation and its command with ``import torch`` failing, on a scene whose exact
    detections give C_var = 0."""
    scene = _scene_with_true_groups(tmp_path, "clean")
    code = textwrap.dedent(f"""
        import sys
        sys.modules["torch"] = None                      # any import of torch now fails
        from click.testing import CliRunner
        from mvm.cli.main import main
        from mvm.eval.cvar import evaluate_cvar
        result = evaluate_cvar([{str(scene)!r}], (0.5,))
        assert abs(result["C_var"]["0.5"]) < 1e-8, result
        run = CliRunner().invoke(main, ["evaluate", "cvar", {str(scene)!r}, "--tau", "0.5",
                                        "--out", {str(tmp_path / "t5.json")!r}])
        assert run.exit_code == 0, run.output
        print("C_var", result["C_var"]["0.5"])
    """)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "src"), os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("C_var") and json.loads((tmp_path / "t5.json").read_text())["scenes"] == {
        "clean": {"0.5": pytest.approx(0.0, abs=1e-8)}}
