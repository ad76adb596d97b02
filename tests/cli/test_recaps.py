"""Recaps fit 80 columns on a terminal, every cell whole, and are tab-separated lines in a
pipe, for every command (``mvm status`` included)."""
import io
from types import SimpleNamespace

import pytest
from rich.console import Console

from mvm.core.keypoints import COCO_KEYPOINTS

CAMERAS = [f"cam{i:02d}" for i in range(10)]


@pytest.fixture
def terminal(monkeypatch):
    """Results on an 80-column terminal: -> a function returning what was printed."""
    import mvm.cli.common as common

    buffer = io.StringIO()
    console = Console(file=buffer, width=80, force_terminal=True, color_system=None)
    monkeypatch.setattr(common, "out", lambda: console)
    monkeypatch.setenv("FORCE_TERMINAL", "1")
    return buffer.getvalue


def _rig_recap(cameras):
    J = len(COCO_KEYPOINTS)
    return {"instants": 300, "persons": 2, "tracks": 2, "tracks_resumed": 0, "instants_per_s": 41.5,
            "joint_flags": {"observed": 0.9}, "keypoints": list(COCO_KEYPOINTS),
            "error_per_keypoint_px": [1.2345 + j for j in range(J)], "views_per_keypoint": [7.5] * J,
            "excluded_per_camera": {n: [0.1234 + 0.01 * v + 0.001 * j for j in range(J)]
                                    for v, n in enumerate(cameras)},
            "excluded_overall_per_camera": {n: 0.2 + 0.01 * v for v, n in enumerate(cameras)}}


def _check_whole(text: str) -> None:
    assert text.strip()
    assert max(len(line) for line in text.splitlines()) <= 80, text
    assert "…" not in text, text


@pytest.mark.parametrize("cameras", [CAMERAS, CAMERAS[:3]])
def test_rig_recap_fits_80_columns(terminal, cameras):
    from mvm.cli.rig import EXCLUDED_NOTE, print_rig_recap

    print_rig_recap("rig: 300 instants", _rig_recap(cameras))
    text = terminal()
    _check_whole(text)
    assert all(name in text for name in COCO_KEYPOINTS) and all(name in text for name in cameras)
    assert text.count(EXCLUDED_NOTE[:40]) == 1                     # the abbreviation explained once
    if len(cameras) == 10:
        assert "cam09" in text and "0.21" in text                   # the worst camera's overall share


def test_rig_recap_in_a_pipe_has_every_column(capsys, monkeypatch):
    from mvm.cli.rig import print_rig_recap

    monkeypatch.delenv("FORCE_TERMINAL", raising=False)
    print_rig_recap("rig", _rig_recap(CAMERAS))
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "# rig" and lines[1].startswith("# excl.: ")
    assert lines[2].split("\t") == ["keypoint", "error px", "views", *[f"excl. {n}" for n in CAMERAS]]
    assert len(lines) == 3 + len(COCO_KEYPOINTS) and all(line.count("\t") == 12 for line in lines[2:])


def test_reconstruct_recap_breaks_paths_between_names(terminal):
    from mvm.cli.scene import recap

    metrics = {"persons": 4, "matched_poses": 123, "unmatched_poses": 7, "E_R_px": 1.23, "outliers": 0.4, "G_k": 5.5}
    timings = {"read_s": 0.1, "total_s": 1.0}
    scenes = ["demo-render/scene", "/data/panoptic/160422_haggling1/hd_00_00-hd_00_30/clip0001"]
    recap([(s, SimpleNamespace(metrics=metrics, timings=timings)) for s in scenes])
    text = terminal()
    _check_whole(text)
    for name in "/".join(scenes).split("/"):
        assert name in text, name                                  # no name folded mid-word
    assert "123" in text and "1.10" in text


def test_status_in_a_pipe_is_tab_separated(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from batch.test_batch import make_root
    from mvm.batch import run_batch
    from mvm.cli.main import main

    monkeypatch.delenv("FORCE_TERMINAL", raising=False)
    root = tmp_path / "root"
    make_root(root, n=2, people=(2, 2), frames=(12, 12), broken=False)
    run_batch(root, ("reconstruct",), workers=1)
    result = CliRunner().invoke(main, ["status", str(root)])
    assert result.exit_code == 0, result.output
    assert not any(ch in result.stdout for ch in "┃│━─┏┡"), result.stdout
    lines = result.stdout.splitlines()
    assert lines[0].startswith(f"# mvm status: {root} — 2 clips: 2 done")
    assert lines[1].split("\t") == ["stage", "done", "skipped", "failed", "running", "pending", "worker s"]
    assert "# data set" in lines and "generated 3D poses\t" in result.stdout
