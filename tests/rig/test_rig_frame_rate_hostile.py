"""A pose file's ``info.video.frame_rate`` that is not a rate (a string, NaN, a negative, 0,
1e308, 1e-300, a list) is one line naming the pose file and the field, exit 2 — never a
traceback nor a silent rate; none recorded (null, missing, no video object) takes the default."""
from __future__ import annotations

import json
import shutil

import pytest
from click.testing import CliRunner

from mvm.cli.rig import rig
from mvm.io.rig_simulation import write_rig_simulation
from mvm.sim.rig_scene import RigSimConfig, simulate_rig


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    root = tmp_path_factory.mktemp("rig") / "rig"
    write_rig_simulation(root, simulate_rig(RigSimConfig(cameras=3, people=1, frames=8, seed=3)))
    return root


@pytest.mark.parametrize("text", ['"30"', "null", "NaN", "-25", "0", "1e308", "1e-300", "[25]", "true",
                                  "Infinity", "MISSING", '{"video": 5}'])
def test_a_recorded_rate_that_is_not_a_rate_is_one_line(base, tmp_path, text):

    root = tmp_path / "rig"
    shutil.copytree(base, root)
    for name in ("cam_01", "cam_02", "cam_03"):
        path = root / "pose" / f"{name}.json"
        data = json.loads(path.read_text())
        video = {"file": f"videos/{name}.mp4", "frames": 8}
        body = json.dumps(data)[1:-1]
        if text == "MISSING":
            info = json.dumps({"video": video})
        elif text.startswith("{"):
            info = text
        else:
            info = json.dumps({"video": video})[:-2] + f', "frame_rate": {text}}}}}'
        path.write_text("{" + body + ', "info": ' + info + "}")
    result = CliRunner().invoke(rig, ["reconstruct", str(root), "--no-refine", "--workers", "1"])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    if text in ("null", "MISSING") or text.startswith("{"):
        assert result.exit_code == 0, result.output
        recap = json.loads((root / "mvm" / "recap.json").read_text())
        assert recap["frame_rate"] == {"hz": 30.0, "source": "default"}, recap["frame_rate"]
        return
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1, result.output
    assert "cam_01.json" in lines[0] and "info.video.frame_rate" in lines[0], lines[0]
    assert not (root / "mvm").exists()
