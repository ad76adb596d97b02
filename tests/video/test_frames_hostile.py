"""``mvm frames`` ends in one line (exit 2) or a result, never a traceback: an output path that
is a file, a record that is a folder (with --force), a record nested 1,020 levels deep (read as
no record: the frames are made again), and a black video (no corner to track: the frames kept
by time alone)."""
from __future__ import annotations

import json

import cv2
import numpy as np
from click.testing import CliRunner

from mvm.cli.main import main

from helpers import write_avi

FRAMES, FPS = 60, 30.0


def _video(tmp_path, black: bool = False):
    rng = np.random.default_rng(1)
    background = rng.integers(0, 255, (96, 128, 3), dtype=np.uint8)
    images = [np.zeros((96, 128, 3), np.uint8) if black else np.roll(background, 2 * i, axis=1)
              for i in range(FRAMES)]
    return write_avi(tmp_path / ("black.avi" if black else "moving.avi"), images, FPS)


def _frames(*args):
    return CliRunner().invoke(main, ["frames", *map(str, args)])


def _one_line(result, *words):
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1, result.output
    for word in words:
        assert word in lines[0], lines[0]


def test_an_output_that_is_a_file_is_one_line(tmp_path):
    video = _video(tmp_path)
    out = tmp_path / "scene"
    out.write_text("my notes\n")
    _one_line(_frames(video, "-o", out), str(out), "not a folder")
    assert out.read_text() == "my notes\n"


def test_a_record_that_is_a_folder_is_one_line_with_force(tmp_path):
    video = _video(tmp_path)
    out = tmp_path / "scene"
    assert _frames(video, "-o", out, "--every-frame").exit_code == 0
    (out / "frames.inputs.json").unlink()
    (out / "frames.inputs.json").mkdir()
    _one_line(_frames(video, "-o", out, "--every-frame", "--force"), "frames.inputs.json", "directory")


def test_a_record_nested_deeper_than_python_recurses_is_no_record(tmp_path):
    video = _video(tmp_path)
    out = tmp_path / "scene"
    assert _frames(video, "-o", out, "--every-frame").exit_code == 0
    record = json.loads((out / "frames.inputs.json").read_text())
    text = json.dumps(record).replace('"settings": {', '"settings": {"deep": ' + '{"a": ' * 1020 + "1"
                                      + "}" * 1020 + ", ", 1)
    (out / "frames.inputs.json").write_text(text)
    result = _frames(video, "-o", out, "--every-frame")
    assert result.exit_code == 0, result.output
    assert "frames: made: its record is unusable" in result.output and "nested deeper" in result.output
    assert len(json.loads((out / "frames.json").read_text())["frames"]) == FRAMES


def test_a_black_video_keeps_frames_by_time(tmp_path):
    video = _video(tmp_path, black=True)
    out = tmp_path / "scene"
    result = _frames(video, "-o", out, "--blur-ratio", "0")
    assert result.exit_code == 0, result.output
    index = json.loads((out / "frames.json").read_text())
    kept = [f["frame"] for f in index["frames"]]
    # nothing to track: one frame a second (max_gap_s) and then min_frames (24) spread in time
    assert len(kept) == 24 and kept[0] == 0 and {0, 30} <= set(kept)
    assert all(f["motion"] is None for f in index["frames"])
    assert cv2.imread(str(out / "frames" / index["frames"][1]["file_name"])).max() <= 2
