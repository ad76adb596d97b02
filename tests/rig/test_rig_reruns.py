"""A rig run that would produce nothing refuses in one line and leaves the previous output set
whole; the set carries the record of its inputs and settings."""
import json

import pytest
from click.testing import CliRunner
from test_rig_dir import _write_rig

from mvm.cli.main import main
from mvm.io.provenance import fingerprint, read_record


@pytest.fixture(scope="module")
def rig_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("rig")
    _write_rig(root, T=6)
    result = CliRunner().invoke(main, ["rig", "reconstruct", str(root), "--workers", "1"])
    assert result.exit_code == 0, result.output
    return root


@pytest.mark.parametrize("frames, problem", [("5000:6000", "selects no frame with 2D poses"),
                                             ("30:10", "selects no frame: STOP (excluded) must be above START")])
def test_an_empty_frame_selection_keeps_the_previous_outputs(rig_dir, frames, problem):
    before = fingerprint(rig_dir / "mvm")
    result = CliRunner().invoke(main, ["rig", "reconstruct", str(rig_dir), "--frames", frames, "--workers", "1"])
    assert result.exit_code == 2, result.output
    assert problem in result.output and len(result.output.strip().splitlines()) == 1
    assert fingerprint(rig_dir / "mvm") == before
    assert (rig_dir / "mvm" / "tracks").is_dir() and (rig_dir / "mvm" / "poses3d.jsonl").stat().st_size > 0


def test_a_scene_directory_is_not_a_rig(tmp_path):
    import numpy as np

    from mvm.io.colmap import write_colmap
    from mvm.sim.tours import cameras_looking_at

    centers = np.stack([np.linspace(-1, 1, 8), np.full(8, -4.0), np.full(8, 1.6)], axis=1)
    cameras = cameras_looking_at(centers, [0.0, 0.0, 1.0], (400.0, 400.0), (480, 270))
    write_colmap(tmp_path / "sparse", cameras)
    (tmp_path / "poses2d.json").write_text(json.dumps({"images": [], "annotations": [], "categories": []}))
    result = CliRunner().invoke(main, ["rig", "reconstruct", str(tmp_path), "--workers", "1"])
    assert result.exit_code == 2, result.output
    assert "not a rig" in result.output and "mvm reconstruct" in result.output
    assert not (tmp_path / "mvm").exists()


def test_the_output_set_records_its_inputs(rig_dir):
    record = read_record(rig_dir / "mvm" / "poses3d.jsonl")
    assert record["stage"] == "the rig reconstruction"
    assert record["inputs"]["Calib.toml"] == fingerprint(rig_dir / "Calib.toml")
    assert record["inputs"]["pose"] == fingerprint(rig_dir / "pose")
    assert "workers" not in record["settings"]["options"]


def test_a_rerun_keeps_an_up_to_date_set_and_redoes_a_changed_one(rig_dir):
    before = fingerprint(rig_dir / "mvm")
    result = CliRunner().invoke(main, ["rig", "reconstruct", str(rig_dir), "--workers", "1"])
    assert result.exit_code == 0, result.output
    assert "output set: kept (up to date)" in result.output and "kept " in result.output
    assert fingerprint(rig_dir / "mvm") == before
    result = CliRunner().invoke(main, ["rig", "reconstruct", str(rig_dir), "--workers", "1", "--smoothing", "none"])
    assert result.exit_code == 0, result.output
    assert "output set: made: setting options.smoothing changed since the rig reconstruction" in result.output
    result = CliRunner().invoke(main, ["rig", "reconstruct", str(rig_dir), "--workers", "1", "--smoothing", "none",
                                       "--force"])
    assert "output set: made: forced" in result.output
