"""One scene's failure, whatever its kind, is that scene's: reported in one line, the other
scenes still done, exit status 2."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from mvm.cli.main import main
from mvm.io.scene_dir import write_scene
from mvm.sim.simulate import SimConfig, simulate


@pytest.fixture(scope="module")
def scenes(tmp_path_factory, bank_poses):
    root = tmp_path_factory.mktemp("scenes")
    scene, _ = simulate(SimConfig(people=2, frames=24, seed=4), bank_poses)
    paths = {}
    for name in ("loop", "good", "bug", "oserror"):
        write_scene(root / name, scene.cameras, scene.poses)
        paths[name] = root / name
    (paths["loop"] / "poses2d.json").unlink()
    (paths["loop"] / "poses2d.json").symlink_to(paths["loop"] / "poses2d.json")      # a symlink loop
    return paths


def test_any_error_is_the_scene_s_own(scenes, monkeypatch):
    import mvm.core.reconstruct as core

    real = core._triangulated

    def flaky(scene, *args, **kwargs):            # the scenes are reconstructed in one batch
        if scene.name == "bug":
            raise RuntimeError("an unexpected bug\nwith two lines")
        if scene.name == "oserror":
            raise PermissionError(13, "Permission denied", str(scenes["oserror"]))
        return real(scene, *args, **kwargs)

    monkeypatch.setattr(core, "_triangulated", flaky)
    order = ["loop", "bug", "good", "oserror"]
    result = CliRunner().invoke(main, ["reconstruct", *(str(scenes[n]) for n in order), "--no-refine"])
    assert result.exit_code == 2, result.output
    errors = [line for line in result.stderr.splitlines() if line.startswith("mvm: error:")]
    assert len(errors) == 3 and "Traceback" not in result.output
    assert str(scenes["loop"]) in errors[0]
    assert errors[1] == f"mvm: error: {scenes['bug']}: RuntimeError: an unexpected bug with two lines"
    assert errors[2] == f"mvm: error: {scenes['oserror']}: PermissionError: [Errno 13] Permission denied: " \
                        f"'{scenes['oserror']}'"
    assert "3 of 4 scene(s) failed" in result.stderr
    document = json.loads((scenes["good"] / "mvm" / "poses3d.json").read_text())
    assert len(document["persons"]) == 2
    assert not any((scenes[n] / "mvm" / "poses3d.json").exists() for n in ("loop", "bug", "oserror"))


def test_export_skips_a_bad_scene_and_exports_the_others(tmp_path, bank_poses):
    from mvm.core.config import Config
    from mvm.scenes import reconstruct_dir

    scene, _ = simulate(SimConfig(people=2, frames=24, seed=5), bank_poses)
    for name in ("good", "missing", "corrupt"):
        write_scene(tmp_path / name, scene.cameras, scene.poses)
    reconstruct_dir(tmp_path / "good", Config(refine=False))
    (tmp_path / "corrupt" / "mvm").mkdir()
    (tmp_path / "corrupt" / "mvm" / "poses3d.json").write_text("[]")
    args = ["export", str(tmp_path / "missing"), str(tmp_path / "good"), str(tmp_path / "corrupt"),
            "--out", str(tmp_path / "ds"), "--link", "none"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    errors = [line for line in result.stderr.splitlines() if line.startswith("mvm: error:")]
    assert len(errors) == 2 and "Traceback" not in result.output
    assert errors[0].startswith(f"mvm: error: {tmp_path / 'missing' / 'mvm' / 'poses3d.json'}: not found")
    assert errors[1].startswith(f"mvm: error: {tmp_path / 'corrupt' / 'mvm' / 'poses3d.json'}")
    assert "2 of 3 scene(s) failed" in result.stderr
    data = json.loads((tmp_path / "ds" / "annotations.json").read_text())
    assert len(data["images"]) == 24 and {im["file_name"].split("/")[0] for im in data["images"]} == {"good"}
