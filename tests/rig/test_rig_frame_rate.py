"""The frame rate of a rig: the videos' rate that ``mvm rig detect`` recorded in the pose files
(``info.video.frame_rate``) unless one is given; cameras that disagree are one line."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from mvm.cli.rig import rig
from mvm.io.rig_simulation import write_rig_simulation
from mvm.sim.rig_scene import RigSimConfig, simulate_rig


@pytest.fixture
def recorded(tmp_path):
    """A simulated rig whose pose files record their videos' rates (``set_rates``)."""
    root = tmp_path / "rig"
    write_rig_simulation(root, simulate_rig(RigSimConfig(cameras=3, people=2, frames=12, seed=2)))

    def set_rates(*rates):
        for name, rate in zip(("cam_01", "cam_02", "cam_03"), rates):
            path = root / "pose" / f"{name}.json"
            data = json.loads(path.read_text())
            data["info"] = {"video": {"file": f"videos/{name}.mp4", "frame_rate": rate, "frames": 12}}
            path.write_text(json.dumps(data))
    return root, set_rates


def _reconstruct(root, *extra):
    return CliRunner().invoke(rig, ["reconstruct", str(root), "--no-refine", "--workers", "1", *extra])


def _recap(root):
    return json.loads((root / "mvm" / "recap.json").read_text())


def test_the_videos_rate_is_used_unless_one_is_given(recorded):
    root, set_rates = recorded
    result = _reconstruct(root)
    assert result.exit_code == 0, result.output
    assert _recap(root)["frame_rate"] == {"hz": 30.0, "source": "default"} and "the default" in result.output
    set_rates(25.0, 25.0, 25.0)
    result = _reconstruct(root)
    assert result.exit_code == 0, result.output
    recap = _recap(root)
    assert recap["frame_rate"] == {"hz": 25.0, "source": "videos"} and recap["options"]["frame_rate"] == 25.0
    assert "frame rate: 25 Hz (the videos'" in result.output
    trc = next((root / "mvm" / "tracks").glob("*.trc")).read_text().splitlines()
    assert trc[1].startswith("DataRate") and trc[2].split("\t")[:2] == ["25", "25"]   # DataRate, CameraRate
    result = _reconstruct(root)                                                # kept: nothing changed
    assert result.exit_code == 0 and "kept (up to date)" in result.output
    result = _reconstruct(root, "--frame-rate", "50")
    assert result.exit_code == 0 and _recap(root)["frame_rate"] == {"hz": 50.0, "source": "setting"}


def test_cameras_that_disagree_on_the_rate_are_one_line(recorded):
    root, set_rates = recorded
    set_rates(25.0, 30.0, 25.0)
    result = _reconstruct(root)
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1, result.output
    assert "cam_01 25 Hz, cam_02 30 Hz, cam_03 25 Hz" in lines[0] and "--frame-rate" in lines[0]
    assert not (root / "mvm").exists()
    result = _reconstruct(root, "--frame-rate", "25")
    assert result.exit_code == 0, result.output
