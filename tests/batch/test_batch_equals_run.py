"""``mvm run CLIP`` and ``mvm batch`` over a folder holding the same clip run the same stages
(:data:`mvm.stages.SCENE_STAGES`) and make the same files: ``poses3d.json`` byte for byte, its
world scaled to metres in both. A rendered clip with its true cameras (imported) and its
projected true joints (imported detections): no SfM, no detector model."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.main import main
from mvm.io.colmap import write_colmap
from mvm.io.provenance import fingerprint, read_record
from mvm.sim.mannequin_video import RenderConfig, render_video

from helpers import coco_results

CONFIG = RenderConfig(frames=8, width=240, height=136, focal_px=200.0, seed=3)
SETTINGS = '[frames]\nblur_ratio = 0\nselect = "all"\n'


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """``(folder, truth)``: ``tour.mp4``, its cameras ``model/``, ``detections.json`` and a
    settings file that keeps every frame."""
    root = tmp_path_factory.mktemp("clip")
    truth = render_video(root / "tour.mp4", CONFIG)
    write_colmap(root / "model", truth.cameras)
    (root / "detections.json").write_text(json.dumps(coco_results(truth, np.random.default_rng(0))))
    (root / "settings.toml").write_text(SETTINGS)
    return root, truth


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_run_and_batch_write_the_same_poses3d(clip, tmp_path):
    source, truth = clip
    scene = tmp_path / "run" / "tour"
    ran = invoke("run", source / "tour.mp4", "-o", scene, "--cameras", source / "model",
                 "--import", source / "detections.json", "--config", source / "settings.toml")
    assert ran.exit_code == 0, ran.output

    root = tmp_path / "batch"                         # the batch's clip: the video, its cameras, its detections
    root.mkdir()
    shutil.copy(source / "tour.mp4", root / "tour.mp4")
    shutil.copytree(source / "model", root / "tour" / "sparse")
    shutil.copy(source / "detections.json", root / "tour.detections.json")
    batched = invoke("batch", root, "--workers", "1", "--stages", "frames,sfm,detect,reconstruct",
                     "--config", source / "settings.toml")
    assert batched.exit_code == 0, batched.output

    run_bytes = (scene / "mvm" / "poses3d.json").read_bytes()
    assert run_bytes == (root / "tour" / "mvm" / "poses3d.json").read_bytes()
    document = json.loads(run_bytes)
    assert document["scale"]["source"] == "people" and document["scale"]["applied_to_model"] is True
    assert len(document["persons"]) == len(truth.poses3d)
    for made in (scene, root / "tour"):               # written once, after the scale: its record has the scaled model
        assert read_record(made / "mvm" / "poses3d.json")["inputs"]["sparse"] == fingerprint(made / "sparse")
        assert read_record(made / "mvm" / "poses3d.json")["settings"]["metric_scale"] is True

    again = invoke("run", source / "tour.mp4", "-o", scene, "--cameras", source / "model",
                   "--import", source / "detections.json", "--config", source / "settings.toml")
    assert again.exit_code == 0, again.output
    assert "reconstruct: kept (up to date)" in again.output
    assert (scene / "mvm" / "poses3d.json").read_bytes() == run_bytes
