"""``mvm rig detect``: a rig's videos -> one COCO pose file per camera, with the detectors of
``mvm detect`` (here an ONNX model with RTMO's signature that reads the joint markers of the
rendered videos: :func:`helpers.marker_rtmo`), the videos' frame rate and frame count recorded,
reruns that redo only the changed videos, and bad input in one line."""
from __future__ import annotations

import functools
import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.rig import rig
from mvm.core.camera import distort
from mvm.io.coco import read_coco_keypoints
from mvm.io.rig_simulation import write_rig_simulation
from mvm.rig.rigdir import read_rig
from mvm.sim.rig_render import render_rig_videos
from mvm.sim.rig_scene import RigSimConfig, simulate_rig

from helpers import marker_rtmo

pytest.importorskip("onnxruntime", reason="onnxruntime is the optional 'detect' extra")
pytest.importorskip("onnx", reason="the test detector is built with the onnx package")

RATE = 25.0
FRAMES = 8


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """2 cameras, 2 people, 8 frames of 640×360 at 25 Hz, lossless videos; the marker detector."""
    root = tmp_path_factory.mktemp("rig")
    sim = simulate_rig(RigSimConfig(cameras=2, people=2, frames=FRAMES, offsets=(0, 2), seed=1, frame_rate=RATE,
                                    image_width=640, image_height=360, focal_px=400.0))
    write_rig_simulation(root / "rig", sim, intrinsics_only=True,
                         render=functools.partial(render_rig_videos, sim=sim, suffix=".mkv"))
    return root / "rig", sim, marker_rtmo(root / "markers.onnx", 2)


def _copy(rendered, tmp_path):
    src, sim, model = rendered
    shutil.copytree(src, tmp_path / "rig")
    return tmp_path / "rig", sim, model


def _detect(root, model, *extra):
    return CliRunner().invoke(rig, ["detect", str(root), "--detector", "rtmo", "--model", str(model), *extra])


def _one_line(result, *words):
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1, result.output
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def test_detect_writes_a_pose_file_per_camera_with_its_video(rendered, tmp_path):
    root, sim, model = _copy(rendered, tmp_path)
    result = _detect(root, model)
    assert result.exit_code == 0, result.output
    cams = sim.calibration.cameras
    errors = []
    for v, name in enumerate(cams.names):
        path = root / "pose" / f"{name}.json"
        info = json.loads(path.read_text())["info"]
        assert info["video"] == {"file": f"videos/{name}.mkv", "frame_rate": RATE, "frames": FRAMES, "width": 640,
                                 "height": 360}
        assert info["detector"] == "rtmo" and info["models"][0]["file"] == "markers.onnx"
        coco = read_coco_keypoints(path)
        assert coco.file_names == tuple(f"{name}/{f:06d}.jpg" for f in range(FRAMES))
        for f in range(FRAMES):                         # every detected joint on its true, distorted projection
            X = sim.poses3d[f + sim.offsets[v] - sim.offsets.min()]
            cam = X @ cams.R[v].T + cams.t[v]
            uv = distort(cam[..., :2] / cam[..., 2:] * cams.K[v][[0, 1], [0, 1]] + cams.K[v][:2, 2], cams.K[v],
                         sim.calibration.distortions[v])
            for kp in coco.keypoints[coco.ann_image == f]:
                seen = kp[:, 2] > 0
                errors.append(np.linalg.norm(kp[seen, None, :2] - uv[:, seen].transpose(1, 0, 2), axis=-1).min(1))
    errors = np.concatenate(errors)
    assert len(errors) > 0.5 * 2 * 2 * FRAMES * 17 and np.median(errors) < 1.0 and np.percentile(errors, 90) < 3.0
    data = read_rig(root, extrinsics=False)
    assert {n: v["frame_rate"] for n, v in data.videos.items()} == {"cam_01": RATE, "cam_02": RATE}
    assert not any(p.name.endswith(".inputs.json") for p in data.sources.values())


def test_reruns_redo_only_the_changed_video(rendered, tmp_path):
    root, _, model = _copy(rendered, tmp_path)
    assert _detect(root, model).exit_code == 0
    result = _detect(root, model, "--batch-size", "3")                     # how it runs, not what it finds
    assert result.exit_code == 0 and result.output.count("kept (up to date)") == 2, result.output
    shutil.copyfile(root / "videos" / "cam_01.mkv", root / "videos" / "cam_02.mkv")
    result = _detect(root, model)
    assert result.exit_code == 0
    rows = {line.split("\t")[0]: line for line in result.output.splitlines() if line.startswith("cam_")}
    assert "kept (up to date)" in rows["cam_01"] and "made: video changed since the rig detection" in rows["cam_02"]
    result = _detect(root, model, "--force")
    assert result.exit_code == 0 and result.output.count("made: forced") == 2, result.output


def test_a_video_that_does_not_decode_is_one_line_and_nothing_is_written(rendered, tmp_path):
    root, _, model = _copy(rendered, tmp_path)
    (root / "videos" / "cam_02.mkv").write_bytes(b"\x1aE\xdf\xa3 not a video at all" * 10)
    _one_line(_detect(root, model), "cam_02", "cam_02.mkv")
    assert not (root / "pose").exists()


def test_pose_files_mvm_did_not_make_are_kept_without_force(rendered, tmp_path):
    root, _, model = _copy(rendered, tmp_path)
    (root / "pose").mkdir()
    (root / "pose" / "cam_01.json").write_text('{"images": [], "annotations": []}')
    _one_line(_detect(root, model), "cam_01.json", "--force")
    assert _detect(root, model, "--force").exit_code == 0


def test_no_videos_is_one_line(tmp_path):
    (tmp_path / "rig").mkdir()
    model = tmp_path / "m.onnx"
    model.write_bytes(b"unused")
    _one_line(_detect(tmp_path / "rig", model), "videos", "cam_01.mp4")


def test_rig_help_lists_the_users_path():
    result = CliRunner().invoke(rig, ["--help"])
    listed = [line.split()[0] for line in result.output.split("Commands:")[1].splitlines() if line.strip()]
    assert listed == ["detect", "synchronize", "calibrate", "reconstruct"]


def test_simulate_rig_videos_writes_what_a_user_brings(tmp_path):
    import cv2

    from mvm.cli.sim import simulate_cmd

    root = tmp_path / "rig"
    result = CliRunner().invoke(simulate_cmd, [str(root), "--rig", "--cameras", "2", "--frames", "20", "--offsets",
                                               "0,3", "--intrinsics-only", "--videos"])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in root.iterdir() if not p.name.startswith(".")) == ["Calib.toml", "videos"]
    assert "rotation" not in (root / "Calib.toml").read_text()
    for name in ("cam_01", "cam_02"):
        capture = cv2.VideoCapture(str(root / "videos" / f"{name}.mp4"))
        frames = 0
        while capture.read()[0]:
            frames += 1
        assert frames == 20 and capture.get(cv2.CAP_PROP_FPS) == 30.0
        assert (capture.get(cv2.CAP_PROP_FRAME_WIDTH), capture.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (1920, 1080)
        capture.release()
    truth = json.loads((tmp_path / "rig.groundtruth.json").read_text())
    assert truth["sync_offsets"] == {"cam_01": 0, "cam_02": 3}
    _one_line(CliRunner().invoke(simulate_cmd, [str(tmp_path / "scene"), "--videos"]), "--videos", "--rig")
    assert not (tmp_path / "scene").exists()


def test_frames_past_what_the_header_announces_are_detected_too():
    """A video whose header counts 3 frames but holds 10: every frame is detected, in order."""
    from mvm.video.detect import DetectOptions, detect_batches
    from mvm.video.detectors import FrameDetector

    def run(frames):
        return [(np.full((1, 17, 3), frame[0, 0, 0], float), np.array([0.9]), None) for frame in frames]

    batches = (([i, i + 1], [np.full((4, 6, 3), i, np.uint8), np.full((4, 6, 3), i + 1, np.uint8)])
               for i in range(0, 10, 2))
    found = detect_batches(batches, 3, FrameDetector(run, {}), DetectOptions(detector="rtmo", appearance="none"))
    found.resize(10)
    keypoints, image, _, _ = found.arrays()
    assert image.tolist() == list(range(10)) and keypoints[:, 0, 0].tolist() == list(range(10))
    assert found.sizes.tolist() == [[6, 4]] * 10 and found.readable.all()


def test_a_pose_file_that_is_a_folder_is_one_line(rendered, tmp_path):
    root, _, model = _copy(rendered, tmp_path)
    (root / "pose" / "cam_01.json").mkdir(parents=True)
    _one_line(_detect(root, model), "cam_01.json")
    assert (root / "pose" / "cam_01.json").is_dir() and not (root / "pose" / "cam_02.json").exists()


@pytest.mark.skipif(not hasattr(__import__("os"), "mkfifo"), reason="no FIFOs on this system")
def test_a_fifo_named_like_a_video_never_hangs(rendered, tmp_path):
    import os
    root, _, model = _copy(rendered, tmp_path)
    os.mkfifo(root / "videos" / "cam_03.mp4")
    _one_line(_detect(root, model), "cam_03.mp4")
    assert not (root / "pose").exists()


def test_a_video_linked_from_outside_the_rig_is_read(rendered, tmp_path):
    root, _, model = _copy(rendered, tmp_path)
    outside = tmp_path / "elsewhere.mkv"
    (root / "videos" / "cam_02.mkv").rename(outside)
    (root / "videos" / "cam_02.mkv").symlink_to(outside)
    result = _detect(root, model)
    assert result.exit_code == 0, result.output
    assert (root / "pose" / "cam_02.json").is_file()


@pytest.mark.parametrize("field, value", [("frames", "many"), ("width", 1e400), ("annotations", 3)])
def test_a_kept_pose_file_with_a_bad_video_record_is_one_line(rendered, tmp_path, field, value):
    root, _, model = _copy(rendered, tmp_path)
    assert _detect(root, model).exit_code == 0
    path = root / "pose" / "cam_01.json"
    data = json.loads(path.read_text())
    if field == "annotations":
        data["annotations"] = value
    else:
        data["info"]["video"][field] = value
    path.write_text(json.dumps(data).replace("Infinity", "1e400"))
    _one_line(_detect(root, model), "cam_01.json", field)


def test_a_camera_named_like_a_record_is_one_line(rendered, tmp_path):
    """``cam_01.inputs.mkv``: its pose file would be ``cam_01``'s record (each overwriting the
    other, and the rig reader skipping it): one line naming the video, nothing written."""
    root, _, model = _copy(rendered, tmp_path)
    shutil.copy(root / "videos" / "cam_01.mkv", root / "videos" / "cam_01.inputs.mkv")
    _one_line(_detect(root, model), "cam_01.inputs.mkv", "camera cam_01.inputs")
    assert not (root / "pose").exists()


@pytest.mark.parametrize("announce", [2 ** 32 - 1, 10 ** 9])
def test_a_video_announcing_billions_of_frames_is_read_as_what_decodes(rendered, tmp_path, announce):
    """cam_02's video re-encoded as a (lossless) AVI whose header claims ``announce`` frames: its
    pose file holds the frames that decode, in memory bounded by the file's size."""
    import tracemalloc

    import cv2

    from helpers import write_avi

    root, _, model = _copy(rendered, tmp_path)
    capture = cv2.VideoCapture(str(root / "videos" / "cam_02.mkv"))
    images = [capture.read()[1] for _ in range(FRAMES)]
    capture.release()
    (root / "videos" / "cam_02.mkv").unlink()
    write_avi(root / "videos" / "cam_02.avi", images, RATE, announce=announce, codec="FFV1")
    tracemalloc.start()
    try:
        result = _detect(root, model)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert result.exit_code == 0, result.output
    assert peak < 200e6, f"{peak / 1e6:.0f} MB"
    info = json.loads((root / "pose" / "cam_02.json").read_text())["info"]["video"]
    assert info == {"file": "videos/cam_02.avi", "frame_rate": RATE, "frames": FRAMES, "width": 640, "height": 360}
    assert len(read_rig(root, extrinsics=False).frames) >= FRAMES


def test_a_pose_path_that_is_a_file_is_one_line(rendered, tmp_path):
    root, _, model = _copy(rendered, tmp_path)
    (root / "pose").write_text("notes\n")
    _one_line(_detect(root, model), "pose", "not a folder")
    assert (root / "pose").read_text() == "notes\n"


def test_a_record_that_is_a_folder_is_one_line_with_force(rendered, tmp_path):
    root, _, model = _copy(rendered, tmp_path)
    assert _detect(root, model).exit_code == 0
    (root / "pose" / "cam_01.inputs.json").unlink()
    (root / "pose" / "cam_01.inputs.json").mkdir()
    _one_line(_detect(root, model, "--force"), "cam_01.inputs.json", "directory")


def test_a_record_nested_deeper_than_python_recurses_is_no_record(rendered, tmp_path):
    root, _, model = _copy(rendered, tmp_path)
    assert _detect(root, model).exit_code == 0
    path = root / "pose" / "cam_01.inputs.json"
    text = json.dumps(json.loads(path.read_text()))
    path.write_text(text.replace('"settings": {', '"settings": {"deep": ' + '{"a": ' * 1020 + "1" + "}" * 1020
                                 + ", ", 1))
    result = _detect(root, model)
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1, result.output                # no record: not mvm's file
    assert "cam_01.json" in lines[0] and "--force" in lines[0], lines[0]
    result = _detect(root, model, "--force")
    assert result.exit_code == 0, result.output
    assert json.loads(path.read_text())["settings"].get("deep") is None


def test_a_camera_name_too_long_for_its_pose_files_is_one_line(rendered, tmp_path):
    root, _, model = _copy(rendered, tmp_path)
    long = "c" * 245
    (root / "videos" / "cam_02.mkv").rename(root / "videos" / f"{long}.mkv")
    _one_line(_detect(root, model), f"{long}.mkv", "at most 200")
    assert not (root / "pose").exists()


def test_a_video_that_ends_early_is_one_line_and_gets_no_pose_file(rendered, tmp_path):
    """cam_02's video cut after 3 of the 8 frames its header and cam_01's announce (a damaged
    file): one line naming it, exit 2, no pose file for it; cam_01's poses are written whole."""
    import cv2

    from helpers import write_avi

    root, _, model = _copy(rendered, tmp_path)
    capture = cv2.VideoCapture(str(root / "videos" / "cam_02.mkv"))
    images = [capture.read()[1] for _ in range(3)]
    capture.release()
    (root / "videos" / "cam_02.mkv").unlink()
    write_avi(root / "videos" / "cam_02.avi", images, RATE, announce=FRAMES, codec="FFV1")
    _one_line(_detect(root, model), "cam_02", "ends early", f"3 of the {FRAMES} frames")
    assert not (root / "pose" / "cam_02.json").exists()
    info = json.loads((root / "pose" / "cam_01.json").read_text())["info"]["video"]
    assert info["frames"] == FRAMES
    # Again, cam_01 kept (up to date): its recorded length is the reference, the cut one refused.
    _one_line(_detect(root, model), "cam_02", "ends early")
    assert not (root / "pose" / "cam_02.json").exists()
