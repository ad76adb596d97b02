"""The scene-directory drivers: many scenes in one call give the files and results of one
scene at a time, in order, each scene's failure its own."""
from __future__ import annotations

import json

import numpy as np
import pytest

from mvm.core.config import Config
from mvm.errors import InputError
from mvm.io.scene_dir import write_scene
from mvm.sim.simulate import SimConfig, simulate


@pytest.fixture(scope="module")
def three(tmp_path_factory, bank_poses):
    root = tmp_path_factory.mktemp("many")
    truths = {}
    for seed, name in enumerate(("a", "b", "c")):
        scene, truth = simulate(SimConfig(people=2, frames=12, seed=20 + seed), bank_poses)
        write_scene(root / name, scene.cameras, scene.poses)
        truths[name] = truth
    return root, truths


def _numbers(path):
    document = json.loads(path.read_text())
    document.pop("timings_s")
    return document


def test_many_scenes_give_what_one_at_a_time_gives(three, tmp_path):
    from mvm.scenes import reconstruct_dir, reconstruct_dirs

    root, truths = three
    config = Config(refine=False)
    paths = [root / n for n in ("c", "a", "b")]
    outcomes = list(reconstruct_dirs(paths, config, "many"))
    assert [p for p, _ in outcomes] == paths                                       # in order
    for path, result in outcomes:
        single = reconstruct_dir(path, config, "one")
        assert _numbers(path / "many" / "poses3d.json") == _numbers(path / "one" / "poses3d.json")
        np.testing.assert_array_equal(result.persons.keypoints3d, single.persons.keypoints3d)
        assert len(result.persons) == len(truths[path.name].poses3d)                # both people found
        assert not list((path / "many").glob(".*.tmp"))                            # no temporary left


def test_a_scene_that_fails_to_read_or_write_is_its_own_failure(three, monkeypatch):
    from mvm import scenes
    from mvm.scenes import reconstruct_dirs

    root, _ = three
    real = scenes.write_poses3d

    def refused(path, document):
        if path.parent.parent.name == "b":
            raise InputError(path, None, "cannot write: no space left on the device")
        real(path, document)

    monkeypatch.setattr(scenes, "write_poses3d", refused)
    paths = [root / "missing", root / "a", root / "b", root / "c"]
    outcomes = dict(reconstruct_dirs(paths, Config(refine=False), "fails"))
    assert list(outcomes) == paths
    assert isinstance(outcomes[root / "missing"], InputError)
    assert "no space left" in str(outcomes[root / "b"]) and not (root / "b" / "fails" / "poses3d.json").exists()
    for name in ("a", "c"):
        assert len(outcomes[root / name].persons) == 2
        assert (root / name / "fails" / "poses3d.json").is_file()
