"""``mvm simulate`` refuses, in one line and exit 2, an option that its mode would ignore:
``--render``, ``--arc``, ``--trajectory``, ``--config`` with ``--rig``; ``--cameras``,
``--offsets``, ``--intrinsics-only``, ``--videos`` without it; ``--video-type`` without
``--videos``. Nothing is written; the options of the mode chosen still work."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from mvm.cli.main import main


@pytest.mark.parametrize("args, option", [
    (["--rig", "--render"], "--render"), (["--rig", "--arc", "30"], "--arc"),
    (["--rig", "--config", "CONFIG"], "--config"), (["--rig", "--trajectory", "TRAJ"], "--trajectory"),
    (["--rig", "--video-type", "mkv"], "--video-type"), (["--cameras", "3"], "--cameras"),
    (["--intrinsics-only"], "--intrinsics-only"), (["--offsets", "0,1"], "--offsets"), (["--videos"], "--videos"),
    (["--video-type", "mp4"], "--video-type"), (["--render", "--video-type", "mkv"], "--video-type"),
])
def test_an_option_the_mode_ignores_is_one_line(tmp_path, args, option):
    config = tmp_path / "settings.toml"
    config.write_text("[simulate]\npeople = 2\n")
    trajectory = tmp_path / "path.txt"
    trajectory.write_text("")
    args = [{"CONFIG": str(config), "TRAJ": str(trajectory)}.get(a, a) for a in args]
    result = CliRunner().invoke(main, ["simulate", str(tmp_path / "out"), "--frames", "20", *args])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1, result.output
    assert lines[0].startswith(f"mvm: error: {option}: ") and "--rig" in lines[0], lines[0]
    assert not (tmp_path / "out").exists()


def test_the_options_of_each_mode_still_work(tmp_path):
    runner = CliRunner()
    result = runner.invoke(main, ["simulate", str(tmp_path / "rig"), "--rig", "--cameras", "2", "--offsets", "0,2",
                                  "--frames", "20", "--people", "1", "--intrinsics-only"])
    assert result.exit_code == 0, result.output
    truth = json.loads((tmp_path / "rig.groundtruth.json").read_text())
    assert truth["sync_offsets"] == {"cam_01": 0, "cam_02": 2}
    config = tmp_path / "settings.toml"
    config.write_text("[simulate]\npeople = 2\n")
    result = runner.invoke(main, ["simulate", str(tmp_path / "scene"), "--arc", "30", "--frames", "20",
                                  "--config", str(config)])
    assert result.exit_code == 0, result.output
    truth = json.loads((tmp_path / "scene.groundtruth.json").read_text())
    assert len(truth["poses3d"]) == 2 and truth["simulation"]["arc_deg"] == 30
