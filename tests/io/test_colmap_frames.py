"""COLMAP 3.12 models link images to frames and frames to rigs: a broken link is one line naming
the file, the record and what is missing (pycolmap says only ``unordered_map::at``)."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from mvm.errors import InputError
from mvm.io.colmap import read_colmap, write_colmap

from helpers import random_cameras


@pytest.fixture
def model(tmp_path):
    write_colmap(tmp_path, random_cameras(np.random.default_rng(0), 3), binary=False)
    return tmp_path


def _edit_frames(model, edit):
    lines = (model / "frames.txt").read_text().splitlines()
    (model / "frames.txt").write_text("\n".join(edit(lines)) + "\n")


def _read(model):
    with pytest.raises(InputError) as e:
        read_colmap(model)
    assert "\n" not in str(e.value) and "unordered_map" not in str(e.value)
    return str(e.value)


def test_a_model_whose_frames_were_removed_names_the_image(model):
    _edit_frames(model, lambda lines: [line for line in lines if line.startswith("#")])
    assert _read(model) == (f"{model / 'images.txt'}: line 5: image 1 (f0000.jpg) is in no frame of frames.txt "
                            "(every image of a COLMAP 3.12 model belongs to a frame)")


def test_one_frame_missing_names_its_image(model):
    _edit_frames(model, lambda lines: [line for line in lines if not line.startswith("2 ")])
    assert "image 2 (f0001.jpg) is in no frame of frames.txt" in _read(model)


def test_a_frame_of_an_image_missing_from_images_names_it(model):
    _edit_frames(model, lambda lines: [line.replace(" CAMERA 1 2", " CAMERA 1 9") for line in lines])
    message = _read(model)
    assert str(model / "images.txt") in message and "image 2 (f0001.jpg) is in no frame" in message
    text = (model / "images.txt").read_text().split("\n")
    drop = next(i for i, line in enumerate(text) if line.startswith("2 "))
    (model / "images.txt").write_text("\n".join(text[:drop] + text[drop + 2:]))
    assert _read(model) == f"{model / 'frames.txt'}: line 5: image 9 is not in images.txt"


def test_a_frame_sensor_outside_its_rig_is_named(model):
    _edit_frames(model, lambda lines: [line.replace(" CAMERA 1 1", " CAMERA 7 1") for line in lines])
    assert _read(model) == f"{model / 'frames.txt'}: line 4: sensor CAMERA 7 is not in rig 1"


def test_a_frame_listing_an_image_under_another_camera_is_named(tmp_path):
    cams = random_cameras(np.random.default_rng(0), 2)
    cams.K[1, 0, 0] *= 2                                           # two cameras, so two sensors in two rigs
    write_colmap(tmp_path, cams, binary=False)
    rigs = (tmp_path / "rigs.txt").read_text()
    (tmp_path / "rigs.txt").write_text(rigs.replace("\n2 1 CAMERA 2", "\n2 2 CAMERA 2 CAMERA 1 0"))
    _edit_frames(tmp_path, lambda lines: [line.replace(" CAMERA 2 2", " CAMERA 1 2") for line in lines])
    assert "image 2 (f0001.jpg) has camera 2, its frame (frames.txt, line 5) lists it under camera 1" in _read(tmp_path)


def test_binary_frames_emptied_names_the_image(tmp_path):
    write_colmap(tmp_path, random_cameras(np.random.default_rng(0), 3), binary=True)
    (tmp_path / "frames.bin").write_bytes(struct.pack("<Q", 0))
    assert _read(tmp_path) == (f"{tmp_path / 'images.bin'}: image 1: image 1 (f0000.jpg) is in no frame of "
                               "frames.bin (every image of a COLMAP 3.12 model belongs to a frame)")


def test_the_written_models_still_read(tmp_path):
    cams = random_cameras(np.random.default_rng(0), 4)
    for binary in (True, False):
        write_colmap(tmp_path / str(binary), cams, binary=binary)
        assert read_colmap(tmp_path / str(binary)).cameras.names == cams.names
