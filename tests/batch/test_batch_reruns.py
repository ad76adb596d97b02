"""``mvm batch`` redoes a stage whose inputs or settings changed since it was done (and says
why), keeps the others; ``mvm status`` shows such stages; ``--force`` redoes everything."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner
from test_batch import make_root

from mvm.batch import batch_status, run_batch
from mvm.batch.stages import BatchOptions
from mvm.cli.main import main
from mvm.core.config import Config

STAGES = ("reconstruct", "export")


@pytest.fixture
def root(tmp_path):
    make_root(tmp_path, n=2, broken=False)
    summary = run_batch(tmp_path, STAGES, workers=1)
    assert summary.done == 2 and not summary.failed and not summary.redone
    return tmp_path


def _drop_last_pose(scene):
    path = scene / "poses2d.json"
    data = json.loads(path.read_text())
    data["annotations"] = data["annotations"][:-1]
    path.write_text(json.dumps(data))


def test_nothing_changed_nothing_redone(root):
    before = (root / "seq00/clip00/mvm/poses3d.json").stat().st_mtime_ns
    summary = run_batch(root, STAGES, workers=1)
    assert summary.committed == 0 and summary.redone == [] and summary.done == 2
    assert (root / "seq00/clip00/mvm/poses3d.json").stat().st_mtime_ns == before
    assert batch_status(root).stale == []


def test_changed_poses_redo_the_reconstruction_and_the_export(root):
    _drop_last_pose(root / "seq00/clip01")
    assert batch_status(root).stale == [
        ("seq00/clip01", "reconstruct", "poses2d.json changed since the reconstruction"),
        ("seq00/clip01", "export", "poses2d.json changed since the export")]
    result = CliRunner().invoke(main, ["status", str(root)])
    assert "out of date: seq00/clip01: reconstruct: poses2d.json changed since the reconstruction" in result.output
    summary = run_batch(root, STAGES, workers=1)
    assert not summary.failed
    assert [(c, s) for c, s, _ in summary.redone] == [("seq00/clip01", "reconstruct"), ("seq00/clip01", "export")]
    assert summary.redone[0][2] == "poses2d.json changed since the reconstruction"
    assert batch_status(root).stale == []


def test_changed_settings_redo_every_clip(root):
    options = BatchOptions(config=Config(tau=0.3))
    summary = run_batch(root, STAGES, workers=1, options=options)
    assert sorted((c, s) for c, s, _ in summary.redone) == [
        ("seq00/clip00", "export"), ("seq00/clip00", "reconstruct"),
        ("seq00/clip01", "export"), ("seq00/clip01", "reconstruct")]
    assert any("setting config.tau changed since the reconstruction" in why for _, _, why in summary.redone)
    assert run_batch(root, STAGES, workers=1, options=options).redone == []


def test_force_redoes_everything(root):
    result = CliRunner().invoke(main, ["batch", str(root), "--stages", ",".join(STAGES), "--workers", "1", "--force"])
    assert result.exit_code == 0, result.output
    assert result.output.count("redone: ") == 4 and "forced" in result.output


def test_status_shows_a_clips_page_and_whether_it_is_up_to_date(root):
    from mvm.stages import run_stage
    from mvm.stages.view import ViewJob
    from mvm.stages.view_report import STAGE as REPORT

    assert batch_status(root).views == []                              # no page made: nothing to say
    assert run_stage(REPORT, ViewJob(root / "seq00/clip00")).why == "no output yet"
    assert batch_status(root).views == [("seq00/clip00", "report", None)]
    _drop_last_pose(root / "seq00/clip00")
    assert batch_status(root).views == [("seq00/clip00", "report", "poses2d.json changed since the report")]
    result = CliRunner().invoke(main, ["status", str(root)])
    assert "out of date: seq00/clip00: report: poses2d.json changed since the report" in result.output
    assert "pages and overlays: 0 of 1 up to date" in result.output
    assert json.loads(CliRunner().invoke(main, ["status", str(root), "--json"]).output)["views"] == [
        {"clip": "seq00/clip00", "stage": "report", "why": "poses2d.json changed since the report"}]
