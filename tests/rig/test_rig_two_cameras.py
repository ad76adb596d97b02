"""A 2-camera rig with the default ``min_group_size`` (3 poses, one per camera) would
reconstruct nobody: it is refused in one line naming the setting and its fix, exit 2, nothing
written; with ``--set min_group_size=2`` the same rig gives back the simulated people."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.rig import rig
from mvm.core.config import Config
from mvm.errors import InputError
from mvm.io.rig_simulation import write_rig_simulation
from mvm.rig.reconstruct_rig import reconstruct_rig
from mvm.sim.rig_scene import RigSimConfig, simulate_rig


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    root = tmp_path_factory.mktemp("rig") / "rig"
    sim = simulate_rig(RigSimConfig(cameras=2, people=2, frames=20, seed=4))
    write_rig_simulation(root, sim)
    return root, sim


def test_a_two_camera_rig_with_groups_of_three_is_one_line(two, tmp_path):
    root, _ = two
    out = tmp_path / "out"
    result = CliRunner().invoke(rig, ["reconstruct", str(root), "-o", str(out), "--no-refine", "--workers", "1"])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1, result.output
    assert "min_group_size" in lines[0] and "has 2" in lines[0] and "--set min_group_size=2" in lines[0], lines[0]
    assert not out.exists()
    with pytest.raises(InputError, match="min_group_size"):
        reconstruct_rig(root, Config(min_group_size=3), output=tmp_path / "lib")


def test_with_groups_of_two_the_rig_gives_back_its_people(two, tmp_path):
    root, sim = two
    out = tmp_path / "out"
    result = CliRunner().invoke(rig, ["reconstruct", str(root), "-o", str(out), "--no-refine", "--workers", "1",
                                      "--set", "min_group_size=2"])
    assert result.exit_code == 0, result.output
    errors = []
    for line in (out / "poses3d.jsonl").read_text().splitlines():
        instant = json.loads(line)
        truth = sim.poses3d[instant["frame"] - sim.instants[0]]                     # (G, 17, 3)
        for person in instant["persons"]:
            X = np.array(person["keypoints3d"], float)[:, :3]
            errors.append(min(np.nanmean(np.linalg.norm(X - t, axis=-1)) for t in truth))
    assert len(errors) >= 0.8 * sim.poses3d.shape[0] * sim.poses3d.shape[1], len(errors)
    assert np.median(errors) < 0.1, np.median(errors)
    assert json.loads((out / "recap.json").read_text())["tracks"] == sim.poses3d.shape[1]
