"""Images read the guarded way: an empty, truncated or undecodable file is one InputError line
naming it (never OpenCV's traceback); readers of many frames skip it with a warning."""
from __future__ import annotations

import logging
import os

import numpy as np
import pytest

from mvm.errors import InputError
from mvm.io.images import UndecodableImage, read_image

cv2 = pytest.importorskip("cv2")

BAD = {"empty.jpg": b"", "text.jpg": b"not an image at all", "header.jpg": b"\xff\xd8\xff\xe0\x00\x10JFIF\x00",
       "png_header.png": b"\x89PNG\r\n\x1a\n" + b"\x00" * 8}


def _jpeg(path, value=90):
    buf = cv2.imencode(".jpg", np.full((20, 30, 3), value, np.uint8))[1]
    path.write_bytes(buf.tobytes())
    return path


@pytest.mark.parametrize("name", sorted(BAD))
def test_an_undecodable_image_is_one_line_naming_it(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(BAD[name])
    with pytest.raises(UndecodableImage) as e:
        read_image(path, root=tmp_path)
    assert str(e.value).startswith(str(path)) and "\n" not in str(e.value)


def test_a_truncated_jpeg_decodes_or_is_refused_never_a_traceback(tmp_path):
    data = _jpeg(tmp_path / "whole.jpg").read_bytes()
    for n in range(0, len(data), 7):
        (tmp_path / "cut.jpg").write_bytes(data[:n])
        try:
            image = read_image(tmp_path / "cut.jpg")
        except UndecodableImage:
            continue
        assert image.ndim == 3 and image.shape[2] == 3


def test_a_good_image_and_the_other_refusals(tmp_path):
    image = read_image(_jpeg(tmp_path / "ok.jpg"))
    assert image.shape == (20, 30, 3) and abs(int(image[5, 5, 0]) - 90) <= 2
    os.mkfifo(tmp_path / "pipe.jpg")
    with pytest.raises(InputError, match="FIFO"):
        read_image(tmp_path / "pipe.jpg")
    with pytest.raises(InputError, match="directory"):
        read_image(tmp_path)
    assert read_image(tmp_path / "missing.jpg", missing_ok=True) is None


def test_predict_refuses_an_undecodable_image_in_one_line(tmp_path):
    from mvm.net.data import load_image

    (tmp_path / "empty.jpg").write_bytes(b"")
    with pytest.raises(InputError, match=r"empty\.jpg: empty file"):
        load_image(tmp_path / "empty.jpg")


def test_detect_skips_an_undecodable_frame_with_a_warning(tmp_path, caplog):
    from mvm.video.detect import read_frames

    frames = tmp_path / "frames"
    frames.mkdir()
    _jpeg(frames / "a.jpg")
    (frames / "b.jpg").write_bytes(b"")
    (frames / "c.jpg").write_bytes(b"garbage")
    with caplog.at_level(logging.WARNING):
        batches = list(read_frames(tmp_path, ["a.jpg", "b.jpg", "c.jpg"], batch_size=8))
    images = batches[0][1]
    assert images[0].shape == (20, 30, 3) and images[1] is None and images[2] is None
    assert "b.jpg" in caplog.text and "c.jpg" in caplog.text
