"""The command line: help, version, demo, and a batch of scenes with one bad one."""
from __future__ import annotations

import json
import os
import subprocess
import sys

from click.testing import CliRunner

from mvm import __version__
from mvm.cli.main import main
from mvm.io.scene_dir import write_scene
from mvm.sim.simulate import SimConfig, simulate


def test_help_and_version():
    runner = CliRunner()
    result = runner.invoke(main, ["--help"])
    assert result.exit_code == 0 and "reconstruct" in result.output and "demo" in result.output
    result = runner.invoke(main, ["--version"])
    assert result.exit_code == 0 and __version__ in result.output
    result = runner.invoke(main, ["reconstruct", "--help"])
    assert result.exit_code == 0 and "--set" in result.output


def test_reconstruct_many_scenes_one_bad(tmp_path, bank_poses):
    good = []
    for seed in (1, 2):
        scene, truth = simulate(SimConfig(people=3, frames=30, seed=seed), bank_poses)
        write_scene(tmp_path / f"good{seed}", scene.cameras, scene.poses)
        good.append(tmp_path / f"good{seed}")
    bad = tmp_path / "bad"
    write_scene(bad, scene.cameras, scene.poses)
    doc = json.loads((bad / "poses2d.json").read_text())
    doc["annotations"][0]["keypoints"] = doc["annotations"][0]["keypoints"][:-3]
    (bad / "poses2d.json").write_text(json.dumps(doc))
    env = {**os.environ, "COLUMNS": "200"}
    proc = subprocess.run([sys.executable, "-m", "mvm", "reconstruct", str(good[0]), str(bad), str(good[1])],
                          capture_output=True, text=True, env=env)
    assert proc.returncode == 2
    errors = [line for line in proc.stderr.splitlines() if line.startswith("mvm: error:")]
    assert len(errors) == 1
    assert f"{bad}/poses2d.json: annotations[0].keypoints: expected 51 numbers" in errors[0]
    assert "Traceback" not in proc.stderr
    for path in good:
        document = json.loads((path / "mvm" / "poses3d.json").read_text())
        assert document["format"] == "mvm.poses3d/1" and len(document["persons"]) == 3
    assert not (bad / "mvm").exists()


def test_bad_setting_is_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "mvm", "reconstruct", str(tmp_path), "--set", "tau=abc"],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip() == "mvm: error: --set: tau: expected float, got 'abc'"


def test_poses3d_has_every_field(tmp_path, bank_poses):
    from mvm.scenes import reconstruct_dir

    scene, truth = simulate(SimConfig(people=2, frames=25, seed=3), bank_poses)
    write_scene(tmp_path / "s", scene.cameras, scene.poses)
    reconstruct_dir(tmp_path / "s")
    document = json.loads((tmp_path / "s" / "mvm" / "poses3d.json").read_text())
    assert len(document["keypoints"]) == 17
    ids = {a["id"] for a in json.loads((tmp_path / "s" / "poses2d.json").read_text())["annotations"]}
    for person in document["persons"]:
        assert set(person) >= {"id", "keypoints3d", "members", "views_per_joint", "reprojection_error_px"}
        assert len(person["keypoints3d"]) == 17 and all(len(k) == 4 for k in person["keypoints3d"])
        assert set(person["members"]) <= ids
        assert len(person["views_per_joint"]) == 17
    assert set(document["metrics"]) >= {"E_R_px", "outliers", "G_k", "persons", "matched_poses", "unmatched_poses"}
    text = (tmp_path / "s" / "mvm" / "poses3d.json").read_text()
    assert "NaN" not in text and "Infinity" not in text


def test_folder_where_a_file_is_wanted_is_one_line(tmp_path):
    """click's own path checks (a folder given for a file option or argument, a missing file that
    must exist) end in mvm's one line naming the option, not a three-line usage message."""
    folder = tmp_path / "a folder"
    folder.mkdir()
    cases = [
        (["rig", "calibrate", str(tmp_path), "--from-people", "-o", str(folder)], "--out"),
        (["reconstruct", str(tmp_path), "--config", str(folder)], "--config"),
        (["frames", str(folder)], "VIDEO"),
        (["simulate", str(tmp_path / "s"), "--trajectory", str(tmp_path / "missing.txt")], "--trajectory"),
    ]
    for args, name in cases:
        r = CliRunner().invoke(main, args)
        lines = r.stderr.strip().splitlines()
        assert r.exit_code == 2, (args, r.output)
        assert len(lines) == 1 and lines[0].startswith(f"mvm: error: {name}: "), (args, lines)
    assert not any(folder.iterdir())


def test_a_required_path_not_given_is_one_line_that_says_so(tmp_path):
    """A required path option left out ends in mvm's one line saying it is required (it said
    ``mvm: error: --output:`` and nothing more)."""
    r = CliRunner().invoke(main, ["rig", "calibrate", str(tmp_path), "--from-people"])
    lines = r.stderr.strip().splitlines()
    assert r.exit_code == 2 and lines == ["mvm: error: --out: required, not given"], r.output
