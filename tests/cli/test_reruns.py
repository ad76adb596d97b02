"""Reruns and results you can trust: a rerun redoes what changed (and says why), keeps the rest,
never replaces cameras or 2D poses mvm did not make without --force, and checks what it can
before any work. A rendered clip, its true cameras as an imported COLMAP model and imported
detections: no SfM, no detector model."""
from __future__ import annotations

import json
import shutil
import time

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.main import main
from mvm.io.colmap import write_colmap
from mvm.io.provenance import fingerprint, read_record
from mvm.sim.mannequin_video import RenderConfig, render_video

from helpers import coco_results

CONFIG = RenderConfig(frames=8, width=240, height=136, focal_px=200.0, seed=3)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    root = tmp_path_factory.mktemp("clip")
    truth = render_video(root / "tour.mp4", CONFIG)
    write_colmap(root / "model", truth.cameras)
    (root / "detections.json").write_text(json.dumps(coco_results(truth, np.random.default_rng(0))))
    return root, truth


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def run(root, scene, *more, detections=None):
    return invoke("run", root / "tour.mp4", "-o", scene, "--cameras", root / "model", "--import",
                  detections or root / "detections.json", "--blur-ratio", "0", "--no-metric", *more)


@pytest.fixture
def scene(clip, tmp_path):
    root, _ = clip
    scene = tmp_path / "scene"
    result = run(root, scene)
    assert result.exit_code == 0, result.output
    return scene


def test_rerun_with_nothing_changed_keeps_every_stage(clip, scene):
    from mvm.stages.run import run_video

    root, _ = clip
    before = {p: p.stat().st_mtime_ns for p in (scene / "frames.json", scene / "poses2d.json",
                                                scene / "mvm" / "poses3d.json", scene / "sfm" / "report.json")}
    result = run(root, scene)
    assert result.exit_code == 0, result.output
    for stage in ("frames", "sfm", "detect", "reconstruct"):
        assert f"{stage}: kept (up to date)" in result.output
    assert {p: p.stat().st_mtime_ns for p in before} == before
    from mvm.video.frames import FrameOptions

    t = time.perf_counter()
    report = run_video(root / "tour.mp4", scene, detections=root / "detections.json", cameras=root / "model",
                       frame_options=FrameOptions(blur_ratio=0), metric_scale=False)
    assert report.why == {"frames": None, "sfm": None, "detect": None, "reconstruct": None}
    assert time.perf_counter() - t < 5


def test_changed_detections_redo_detection_and_reconstruction(clip, scene, tmp_path):
    root, truth = clip
    other = tmp_path / "detections.json"
    shutil.copy(root / "detections.json", other)
    assert run(root, scene, detections=other).exit_code == 0     # another path, the same bytes: kept
    assert read_record(scene / "poses2d.json")["inputs"]["detections"] == fingerprint(root / "detections.json")
    other.write_text(json.dumps(coco_results(truth, np.random.default_rng(1))))
    result = run(root, scene, detections=other)
    assert result.exit_code == 0, result.output
    assert "frames: kept (up to date)" in result.output and "sfm: kept (up to date)" in result.output
    assert "detect: made: detections changed since the detection" in result.output
    assert "reconstruct: made: poses2d.json changed since the reconstruction" in result.output


def test_new_frame_options_redo_frames_and_what_follows(clip, scene):
    root, _ = clip
    result = run(root, scene, "--max-frames", "6")
    assert result.exit_code == 0, result.output
    assert "frames: made: setting max_frames changed since the frame extraction (null -> 6)" in result.output
    assert "detect: made: frames" in result.output
    assert len(list((scene / "frames").glob("*.jpg"))) == 6       # the other frames are gone


def test_frames_command_redoes_on_new_options(clip, scene):
    root, _ = clip
    result = invoke("frames", root / "tour.mp4", "-o", scene, "--blur-ratio", "0", "--width", "120")
    assert result.exit_code == 0, result.output
    assert "frames: made: setting width changed" in result.output
    assert json.loads((scene / "frames.json").read_text())["width"] == 120


def test_report_refuses_a_reconstruction_older_than_its_poses(clip, scene, tmp_path):
    root, truth = clip
    fewer = tmp_path / "fewer.json"
    fewer.write_text(json.dumps(coco_results(truth, np.random.default_rng(0), skip=1)))
    result = invoke("detect", scene, "--import", fewer)
    assert result.exit_code == 0, result.output
    assert "2D poses: made: detections changed since the detection" in result.output
    for command in (("report", scene), ("overlay", scene), ("export", scene, "--out", tmp_path / "set")):
        result = invoke(*command)
        assert result.exit_code == 2, result.output
        assert "out of date: poses2d.json changed since the reconstruction" in result.output
        assert f"mvm reconstruct {scene}" in result.output
    assert invoke("reconstruct", scene).exit_code == 0
    result = invoke("report", scene, "--frames", "0")
    assert result.exit_code == 0, result.output


def test_sfm_never_replaces_a_model_it_did_not_make(clip, tmp_path):
    root, truth = clip
    scene = tmp_path / "scene"
    assert invoke("frames", root / "tour.mp4", "-o", scene, "--blur-ratio", "0").exit_code == 0
    write_colmap(scene / "sparse", truth.cameras)                  # cameras from elsewhere
    before = fingerprint(scene / "sparse")
    for command in (("sfm", scene), ("sfm", scene, "--cameras", root / "model")):
        result = invoke(*command)
        assert result.exit_code == 2, result.output
        assert "a camera model mvm did not make: give --force to replace it" in result.output
        assert len(result.output.strip().splitlines()) == 1
    assert fingerprint(scene / "sparse") == before
    result = invoke("sfm", scene, "--cameras", scene / "sparse")   # adopted as it is
    assert result.exit_code == 0, result.output
    assert fingerprint(scene / "sparse") == before
    result = invoke("sfm", scene)                                 # imported: not replaced by SfM's
    assert result.exit_code == 2 and "give --force to replace them with SfM's" in result.output
    assert fingerprint(scene / "sparse") == before


def test_the_scene_s_own_model_adopted_again_is_read_again(clip, tmp_path):
    """``mvm sfm SCENE --cameras SCENE/sparse`` after the user edited ``sparse/``: the report
    follows the model as it is now (the scene's own model is no input the record could hold)."""
    from mvm.video.sfm import read_sfm_report

    root, truth = clip
    scene = tmp_path / "scene"
    assert invoke("frames", root / "tour.mp4", "-o", scene, "--blur-ratio", "0").exit_code == 0
    write_colmap(scene / "sparse", truth.cameras)
    assert invoke("sfm", scene, "--cameras", scene / "sparse").exit_code == 0
    assert len(read_sfm_report(scene).registered) == len(truth.cameras)
    write_colmap(scene / "sparse", truth.cameras.subset(list(range(len(truth.cameras) - 2))))
    result = invoke("sfm", scene, "--cameras", scene / "sparse")
    assert result.exit_code == 0, result.output
    assert len(read_sfm_report(scene).registered) == len(truth.cameras) - 2


def test_detect_never_replaces_poses_it_did_not_make(clip, scene):
    root, _ = clip
    (scene / "poses2d.inputs.json").unlink()                      # as if written by another tool
    before = fingerprint(scene / "poses2d.json")
    result = invoke("detect", scene, "--import", root / "detections.json")
    assert result.exit_code == 2, result.output
    assert "2D poses mvm did not make" in result.output and "--force" in result.output
    assert fingerprint(scene / "poses2d.json") == before
    result = invoke("detect", scene, "--import", root / "detections.json", "--force")
    assert result.exit_code == 0, result.output


def test_detections_of_frames_of_another_size_are_refused_before_any_work(clip, tmp_path):
    root, truth = clip
    big = tmp_path / "big.json"
    big.write_text(json.dumps(coco_results(truth, np.random.default_rng(0), scale=2.0)))
    scene = tmp_path / "scene"
    result = run(root, scene, detections=big)
    assert result.exit_code == 2, result.output
    assert "outside the 240×136 frames" in result.output
    assert not (scene / "frames.json").exists()
    result = invoke("run", root / "tour.mp4", "-o", scene, "--cameras", root / "model", "--import", big,
                    "--width", "480", "--blur-ratio", "0", "--no-metric")
    assert result.exit_code == 0, result.output                  # frames at the detections' size
    assert "outside" not in result.output


def test_detections_naming_no_frame_are_refused(clip, scene, tmp_path):
    root, truth = clip
    results = coco_results(truth, np.random.default_rng(0))
    for r in results:
        r["image_id"] = "img_" + r["image_id"]
    other = tmp_path / "other.json"
    other.write_text(json.dumps(results))
    result = invoke("detect", scene, "--import", other)
    assert result.exit_code == 2, result.output
    assert "no detection is of a frame of" in result.output and "frame_00000.jpg" in result.output


def test_rtmpose_models_are_checked_before_any_work(clip, tmp_path):
    root, _ = clip
    scene = tmp_path / "scene"
    result = invoke("run", root / "tour.mp4", "-o", scene, "--detector", "rtmpose",
                    "--person-model", tmp_path / "yolox.onnx", "--model", tmp_path / "rtmpose.onnx")
    assert result.exit_code == 2, result.output
    line = result.output.strip()
    assert f"--person-model {tmp_path / 'yolox.onnx'}: model file not found" in line
    assert f"--model {tmp_path / 'rtmpose.onnx'}: model file not found" in line
    assert not (scene / "frames.json").exists()


def test_force_redoes_every_stage(clip, scene):
    root, _ = clip
    result = run(root, scene, "--force", "all")
    assert result.exit_code == 0, result.output
    for stage in ("frames", "sfm", "detect", "reconstruct"):
        assert f"{stage}: made: forced" in result.output


def test_rerun_decides_each_stage_from_one_hashing_of_its_inputs(clip, scene, monkeypatch):
    """A rerun with nothing changed hashes each stage's inputs once to decide whether to redo it
    (files written in the last seconds are not in the hash cache: a second hashing reads them
    all again; a video of a GB costs a second each time)."""
    from collections import Counter

    from mvm.io import provenance

    root, _ = clip
    calls, hash_file = Counter(), provenance._hash_file

    def counted(path):
        calls[path.name] += 1
        return hash_file(path)

    monkeypatch.setattr(provenance, "_hash_file", counted)
    result = run(root, scene)
    assert result.exit_code == 0, result.output
    assert calls["tour.mp4"] == 1 and calls["detections.json"] == 1, calls
    assert calls["poses2d.json"] == 1, calls                        # read by the reconstruction only
