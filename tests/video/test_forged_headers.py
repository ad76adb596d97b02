"""A video's header is not believed: a few-kB AVI announcing billions of frames is read as the
frames that decode, in memory bounded by the file's size and ``MVM_MAX_VIDEO_FRAMES`` (``mvm
frames`` here; ``mvm rig detect`` in ``test_rig_videos.py``). Each command runs in a process
whose heap is limited to 1 GiB, so that believing the header fails fast instead of swapping."""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys

import cv2
import numpy as np
import pytest

from mvm.io.images import count_frames, frame_count_bound

from helpers import write_avi

FRAMES = 5
HEAP_LIMIT = 2 ** 30


def moving_dot(n: int = FRAMES, size: tuple[int, int] = (64, 48)):
    """``n`` frames (h, w = size[1], size[0]) of a textured background and a dot moving right."""
    rng = np.random.default_rng(0)
    background = rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)
    for i in range(n):
        image = background.copy()
        cv2.circle(image, (8 + 8 * i, size[1] // 2), 5, (255, 255, 255), -1)
        yield image


def run_mvm(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """``mvm ARGS`` in a process of at most :data:`HEAP_LIMIT` bytes of heap."""
    def limit():
        resource.setrlimit(resource.RLIMIT_DATA, (HEAP_LIMIT, HEAP_LIMIT))

    return subprocess.run([sys.executable, "-m", "mvm", *args], capture_output=True, text=True, timeout=300,
                          preexec_fn=limit, env={**os.environ, "COLUMNS": "200", **(env or {})})


@pytest.mark.parametrize("announce", [2 ** 32 - 1, 10 ** 9])
@pytest.mark.parametrize("options, kept", [(("--rate", "1"), [0]), (("--max-frames", "3"), [0, 2, 4]),
                                           ((), None)], ids=["rate", "max_frames", "motion"])
def test_frames_of_a_video_announcing_billions_of_frames(tmp_path, announce, options, kept):
    video = write_avi(tmp_path / "v.avi", moving_dot(), announce=announce)
    assert cv2.VideoCapture(str(video)).get(cv2.CAP_PROP_FRAME_COUNT) == announce      # the header lies
    assert video.stat().st_size < 20_000
    proc = run_mvm("frames", str(video), "-o", str(tmp_path / "scene"), *options)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    numbers = [f["frame"] for f in json.loads((tmp_path / "scene" / "frames.json").read_text())["frames"]]
    assert numbers and max(numbers) < FRAMES
    if kept is not None:                       # every frame decodes: blur skips none of the dot's frames
        assert numbers == kept


def test_the_frame_count_bound_and_the_frames_counted(tmp_path):
    video = write_avi(tmp_path / "v.avi", moving_dot(), announce=10 ** 9)
    size = video.stat().st_size
    assert frame_count_bound(video, 10 ** 9) == size
    assert frame_count_bound(video, 3) == 3
    assert frame_count_bound(video, float("nan")) == frame_count_bound(video, -1) == 0
    assert frame_count_bound(tmp_path / "missing.avi", 10) == 0
    capture = cv2.VideoCapture(str(video))
    assert count_frames(capture, video) == FRAMES
    capture.release()


def test_frames_past_the_limit_are_not_read(tmp_path):
    video = write_avi(tmp_path / "v.avi", moving_dot(8))
    proc = run_mvm("frames", str(video), "-o", str(tmp_path / "scene"), "--every-frame", "--blur-ratio", "0",
                   env={"MVM_MAX_VIDEO_FRAMES": "3"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    numbers = [f["frame"] for f in json.loads((tmp_path / "scene" / "frames.json").read_text())["frames"]]
    assert numbers == [0, 1, 2]
    assert "only its first 3 frames are read (MVM_MAX_VIDEO_FRAMES)" in proc.stderr
