"""``sfm/scale.json`` (the scale ``sparse/`` was brought to, relative to SfM's units) as a
hostile file: not JSON, the wrong type, zero or negative, a FIFO, a link out of the scene, a
folder. Each is passed over with a warning naming the file: the model is taken in SfM's units;
nothing hangs and nothing is read outside the scene."""
from __future__ import annotations

import json
import logging
import os

import pytest

from mvm.io.layout import SceneLayout
from mvm.video.metric_scale import _read_scale


def _scene(tmp_path):
    scene = tmp_path / "scene"
    (scene / "sfm").mkdir(parents=True)
    return scene, SceneLayout(scene).scale_file


def test_a_scale_mvm_wrote_is_read(tmp_path):
    scene, path = _scene(tmp_path)
    path.write_text(json.dumps({"sfm_units_per_model_unit": 0.25}))
    assert _read_scale(scene) == 0.25
    path.unlink()
    assert _read_scale(scene) == 1.0                                              # never scaled


@pytest.mark.parametrize("content, said", [
    ("{not json", "scale.json"), ('{"sfm_units_per_model_unit": "2"}', "expected a number"),
    ('{"sfm_units_per_model_unit": 0}', "expected a positive number"),
    ('{"sfm_units_per_model_unit": -3.5}', "expected a positive number"),
    ('{"sfm_units_per_model_unit": 1e999}', "sfm_units_per_model_unit"), ("[1, 2]", "scale.json"),
])
def test_a_bad_scale_file_is_passed_over_with_a_warning(tmp_path, caplog, content, said):
    scene, path = _scene(tmp_path)
    path.write_text(content)
    with caplog.at_level(logging.WARNING, logger="mvm.video.metric_scale"):
        assert _read_scale(scene) == 1.0
    assert said in caplog.text and "assuming the model is in SfM units" in caplog.text


def test_a_fifo_a_link_out_or_a_folder_is_never_read(tmp_path, caplog):
    scene, path = _scene(tmp_path)
    os.mkfifo(path)                                                               # would block a reader
    with caplog.at_level(logging.WARNING, logger="mvm.video.metric_scale"):
        assert _read_scale(scene) == 1.0
    path.unlink()
    outside = tmp_path / "elsewhere.json"
    outside.write_text(json.dumps({"sfm_units_per_model_unit": 7.0}))
    path.symlink_to(outside)
    assert _read_scale(scene) == 1.0
    path.unlink()
    path.mkdir()
    assert _read_scale(scene) == 1.0
