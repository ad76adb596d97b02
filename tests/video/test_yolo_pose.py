"""The YOLO-pose adapter on tiny ONNX models made here (``onnx.helper``) with an Ultralytics
YOLO-pose export's signature, ``images (B, 3, 64, 64)`` -> ``output0 (B, 56, 8)``: candidates
given in letterboxed input pixels, some of whose scores read the input's pixels (RGB order,
[0, 1] scaling, grey 114 and the padding's exact rows and columns). Every expected pose is
computed here from Ultralytics' letterbox rules worked out by hand for two frame sizes."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from mvm.errors import InputError
from mvm.io.coco import read_coco_keypoints
from mvm.video.detect import DetectOptions, detect_scene
from mvm.video.yolo_pose import YoloPose, YoloPoseOptions, letterbox_geometry

pytest.importorskip("onnxruntime", reason="onnxruntime is the optional 'detect' extra")
onnx = pytest.importorskip("onnx", reason="the test models are built with the onnx package")

J, S, GREY = 17, 64, 114 / 255

# The two frames (W × H) and their letterbox into 64 × 64, by hand: r = min(64 / H, 64 / W) = 0.32;
# 200 × 90 resizes to 64 × round(28.8) = 29, vertical padding 35 = 17 above (round(17.5 - 0.1))
# and 18 below; 90 × 200 resizes to 29 × 64, 17 columns left and 18 right.
WIDE, TALL = (200, 90), (90, 200)
OFFSET = {WIDE: np.array([0.0, 17.0]), TALL: np.array([17.0, 0.0])}
SCALE = {WIDE: np.array([64 / 200, 29 / 90]), TALL: np.array([29 / 90, 64 / 200])}

# Candidates: box centre x, y, w, h in input pixels and a score; a score given as (channel, x, y)
# is the input's value there (filled in by the model from the image).
CANDIDATES = [
    ((32, 32, 20, 20), 0.9),             # A
    ((33, 32, 20, 20), 0.8),             # A again, one pixel right: IoU 0.905 > 0.7, suppressed
    ((40, 32, 20, 20), 0.7),             # D, overlapping A by IoU 0.43: kept (dropped at iou 0.4)
    ((10, 10, 6, 6), 0.25),              # not above the 0.25 threshold: dropped
    ((54, 10, 6, 6), 0.2),               # below the threshold: dropped (kept at 0.1)
    ((50, 50, 4, 4), (0, 20, 17)),       # red at the first row of WIDE's image: 1; TALL: inside, 1
    ((56, 8, 4, 4), (1, 20, 16)),        # green at the last padding row of WIDE: 114/255; TALL: 0
    ((8, 56, 4, 4), (0, 16, 40)),        # red at TALL's last padding column: 114/255; WIDE: 1
]
N = len(CANDIDATES)


def _keypoints(n: int) -> np.ndarray:
    """Candidate ``n``'s 17 keypoints (x, y, confidence) in input pixels: inside both frames'
    images (x and y in 20…44), but joint 16 in the padding's corner (clipped to the frame);
    joint 3 at the 0.05 floor (missing), joint 4 just above it."""
    j = np.arange(J)
    xy = np.stack([20 + j * 1.25 + n * 0.5, 44 - j * 1.5 + n * 0.25], -1)
    xy[16] = (2.0, 2.0)
    conf = np.linspace(0.3, 1.0, J)
    conf[3], conf[4] = 0.05, 0.0501
    return np.concatenate([xy, conf[:, None]], 1)


def _base() -> tuple[np.ndarray, np.ndarray]:
    """The constant part ``(1, 56, N)`` and the mask of the input-read scores."""
    base, read = np.zeros((1, 56, N), np.float32), np.zeros((1, 56, N), np.float32)
    for n, (box, score) in enumerate(CANDIDATES):
        base[0, :4, n] = box
        base[0, 5:, n] = _keypoints(n).reshape(-1)
        if isinstance(score, tuple):
            read[0, 4, n] = 1.0
        else:
            base[0, 4, n] = score
    return base, read


def _builder():
    """``(nodes, inits, const, op)``: a graph under construction."""
    from onnx import helper as h
    from onnx.numpy_helper import from_array

    nodes, inits = [], []

    def const(name, value, dtype=np.float32):
        inits.append(from_array(np.asarray(value, dtype=dtype), name))
        return name

    def op(kind, inputs, output, **attrs):
        nodes.append(h.make_node(kind, inputs, [output], **attrs))
        return output

    return nodes, inits, const, op


def _save(path, nodes, inits, input_shape, output_shape):
    from onnx import TensorProto
    from onnx import helper as h

    graph = h.make_graph(nodes, "tiny_yolo_pose", [h.make_tensor_value_info("images", TensorProto.FLOAT, input_shape)],
                         [h.make_tensor_value_info("output0", TensorProto.FLOAT, output_shape)], inits)
    model = h.make_model(graph, opset_imports=[h.make_opsetid("", 17)], ir_version=8)
    onnx.checker.check_model(model)
    onnx.save(model, path)
    return path


def yolo_model(path, batch="B", gate=False):
    """The tiny YOLO-pose model: ``images (batch, 3, 64, 64)`` -> ``output0 (batch, 56, 8)``.
    ``gate``: every score times the red channel at the input's centre (an all-blue frame
    then gives no candidate)."""
    nodes, inits, const, op = _builder()

    def pixel(c, x, y, name):                                           # images[:, c, y, x] as (B, 1, 1)
        value = op("Slice", ["images", const(f"{name}s", [c, y, x], np.int64),
                             const(f"{name}e", [c + 1, y + 1, x + 1], np.int64),
                             const(f"{name}a", [1, 2, 3], np.int64)], f"{name}v")
        return op("Reshape", [value, const(f"{name}r", [-1, 1, 1], np.int64)], name)

    base, _ = _base()
    out = op("Mul", [const("zero", 0.0), pixel(0, 0, 0, "any")], "batch0")          # (B, 1, 1) zeros
    out = op("Add", [const("base", base), out], "out0")
    for n, (_, score) in enumerate(CANDIDATES):
        if isinstance(score, tuple):
            mask = np.zeros((1, 56, N), np.float32)
            mask[0, 4, n] = 1.0
            out = op("Add", [out, op("Mul", [const(f"m{n}", mask), pixel(*score, f"p{n}")], f"read{n}")], f"out{n + 1}")
    if gate:
        keep = np.ones((1, 56, N), np.float32)
        keep[0, 4] = 0.0
        score = op("Mul", [const("only4", 1 - keep), pixel(0, 32, 32, "centre")], "gscore")
        out = op("Mul", [out, op("Add", [const("keep", keep), score], "gmul")], "gated")
    nodes[-1].output[0] = "output0"
    return _save(path, nodes, inits, [batch, 3, S, S], [batch, 56, N])


def constant_model(path, input_shape, channels):
    """A model of any input layout whose output ``(1, channels, 8)`` is constant."""
    nodes, inits, const, op = _builder()
    total = op("ReduceSum", ["images"], "total", keepdims=0)
    op("Add", [const("base", np.zeros((1, channels, N))), op("Mul", [total, const("zero", 0.0)], "nil")], "output0")
    return _save(path, nodes, inits, input_shape, [1, channels, N])


def _red(size):
    """An all-red BGR frame of ``size`` (W, H)."""
    frame = np.zeros((size[1], size[0], 3), np.uint8)
    frame[..., 2] = 255
    return frame


def _expected(size, options=YoloPoseOptions()):
    """The poses (keypoints (K, 17, 3), scores (K,)) the detector must report for an all-red frame
    of ``size``, best first: the candidates' scores as the model reads them, Ultralytics'
    threshold (strictly above) and NMS (worked out above), then the letterbox undone."""
    red_scores = {WIDE: [1.0, GREY, 1.0], TALL: [1.0, 0.0, GREY]}[size]
    scores = [s if not isinstance(s, tuple) else red_scores[k - 5] for k, (_, s) in enumerate(CANDIDATES)]
    suppressed = {1} | ({2} if options.iou_threshold < 0.43 else set())
    kept = [n for n in range(N) if scores[n] > options.score_threshold and n not in suppressed]
    kept.sort(key=lambda n: -scores[n])
    keypoints = []
    for n in kept:
        kp = _keypoints(n)
        xy = np.clip((kp[:, :2] - OFFSET[size]) / SCALE[size], 0, size)
        v = np.where(kp[:, 2] > options.keypoint_floor, kp[:, 2], 0.0)
        keypoints.append(np.concatenate([np.where(v[:, None] > 0, xy, 0.0), v[:, None]], 1))
    return np.array(keypoints).reshape(-1, J, 3), np.array([scores[n] for n in kept])


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    folder = tmp_path_factory.mktemp("yolo")
    return {"dynamic": yolo_model(folder / "dynamic.onnx"), "one": yolo_model(folder / "one.onnx", batch=1),
            "gated": yolo_model(folder / "gated.onnx", gate=True),
            "57": constant_model(folder / "57.onnx", [1, 3, S, S], 57),
            "flat": constant_model(folder / "flat.onnx", [1, 3 * S * S], 56),
            "grey": constant_model(folder / "grey.onnx", [1, 1, S, S], 56)}


def test_letterbox_geometry_rounds_the_padding_as_ultralytics():
    assert letterbox_geometry(90, 200, (64, 64))[:2] == ((64, 29), (0, 17, 0, 18))
    assert letterbox_geometry(200, 90, (64, 64))[:2] == ((29, 64), (17, 0, 18, 0))
    assert letterbox_geometry(1920, 1080, (640, 640))[:2] == ((360, 640), (140, 0, 140, 0))


@pytest.mark.parametrize("name", ["dynamic", "one"])
def test_poses_back_in_frame_pixels_thresholded_suppressed_and_floored(models, name):
    detector = YoloPose(models[name])
    assert detector.model.batched == (name == "dynamic") and detector.size == (S, S)
    found = detector([_red(WIDE), _red(TALL)])                      # one batch, two frame sizes
    for (kp, score), size in zip(found, [WIDE, TALL]):
        want_kp, want_score = _expected(size)
        assert score == pytest.approx(want_score, abs=1e-6)
        assert kp.shape == want_kp.shape
        assert np.abs(kp - want_kp).max() < 1e-3
        assert (kp[:, 3] == 0).all() and (kp[:, 4, 2] > 0).all()    # at the floor: missing, x = y = 0


def test_thresholds_are_the_settings(models):
    options = YoloPoseOptions(score_threshold=0.1, iou_threshold=0.4, keypoint_floor=0.6)
    kp, score = YoloPose(models["dynamic"], options=options)([_red(WIDE)])[0]
    want_kp, want_score = _expected(WIDE, options)
    assert 0.2 in np.round(score, 6) and 0.7 not in np.round(score, 6)       # C found, D suppressed
    assert score == pytest.approx(want_score, abs=1e-6) and np.abs(kp - want_kp).max() < 1e-3


@pytest.mark.parametrize("name, problem", [("57", "expected the output (batch, 56, candidates)"),
                                           ("flat", "expected an image input"), ("grey", "expected an image input")])
def test_a_model_of_another_layout_is_refused_in_one_line(models, name, problem):
    with pytest.raises(InputError, match=problem.replace("(", r"\(").replace(")", r"\)")) as e:
        YoloPose(models[name])
    assert "\n" not in str(e.value) and str(models[name]) in str(e.value)


def _scene(folder, frames):
    (folder / "frames").mkdir(parents=True)
    for k, frame in enumerate(frames):
        cv2.imwrite(str(folder / "frames" / f"frame_{k:05d}.png"), frame)
    return folder


def test_cli_detect_writes_the_scene_poses(models, tmp_path):
    from mvm.cli.video import detect_cmd

    scene = _scene(tmp_path / "scene", [_red(WIDE), _red(WIDE)])
    result = CliRunner().invoke(detect_cmd, [str(scene), "--detector", "yolo-pose", "--model",
                                             str(models["dynamic"])])
    assert result.exit_code == 0, result.output
    coco = read_coco_keypoints(scene / "poses2d.json")
    want_kp, want_score = _expected(WIDE)
    assert len(coco.keypoints) == 2 * len(want_kp)
    assert np.abs(coco.keypoints[coco.ann_image == 1] - want_kp).max() < 1e-3
    assert coco.appearance is not None                                       # the colour descriptor
    info = json.loads((scene / "poses2d.json").read_text())["info"]
    assert info["detector"] == "yolo-pose" and info["models"][0]["file"] == "dynamic.onnx"


def test_settings_file_thresholds_reach_the_detector(models, tmp_path):
    from mvm.cli.video import detect_cmd

    scene = _scene(tmp_path / "scene", [_red(WIDE)])
    settings = tmp_path / "settings.toml"
    settings.write_text("[detect.yolo]\nscore_threshold = 0.95\n")
    result = CliRunner().invoke(detect_cmd, [str(scene), "--detector", "yolo-pose", "--model", str(models["one"]),
                                             "--config", str(settings)])
    assert result.exit_code == 0, result.output
    assert read_coco_keypoints(scene / "poses2d.json").score.tolist() == pytest.approx([1.0, 1.0])
    poses = detect_scene(scene, options=DetectOptions(detector="yolo-pose", model=str(models["one"]),
                                                      yolo=YoloPoseOptions(score_threshold=0.5)))
    assert poses.why is not None and poses.score.tolist() == pytest.approx([1.0, 1.0, 0.9, 0.7])


@pytest.mark.parametrize("args, problem", [([], "yolo-pose needs an Ultralytics YOLO-pose ONNX export"),
                                           (["--model", "missing.onnx"], "missing.onnx: model file not found")])
def test_cli_without_its_model_is_one_line_exit_2(tmp_path, args, problem):
    from mvm.cli.video import detect_cmd

    scene = _scene(tmp_path / "scene", [_red(WIDE)])
    result = CliRunner().invoke(detect_cmd, [str(scene), "--detector", "yolo-pose", *args])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1 and problem in lines[0], result.output
    assert not (scene / "poses2d.json").exists()


def test_not_an_onnx_file_is_one_line_exit_2(tmp_path):
    from mvm.cli.video import detect_cmd

    scene = _scene(tmp_path / "scene", [_red(WIDE)])
    bad = tmp_path / "yolo.onnx"
    bad.write_text("not a model")
    result = CliRunner().invoke(detect_cmd, [str(scene), "--detector", "yolo-pose", "--model", str(bad)])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1 and "cannot load the ONNX model" in lines[0], result.output
    assert not (scene / "poses2d.json").exists()


def _video(path, frames, size, colour):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 25.0, size)      # lossless
    frame = np.zeros((size[1], size[0], 3), np.uint8)
    frame[:] = colour
    for _ in range(frames):
        writer.write(frame)
    writer.release()


def test_cli_rig_detect_writes_a_pose_file_per_camera(models, tmp_path):
    from mvm.cli.rig import rig

    (tmp_path / "videos").mkdir()
    _video(tmp_path / "videos" / "cam_a.avi", 5, WIDE, (0, 0, 255))
    _video(tmp_path / "videos" / "cam_b.avi", 3, TALL, (0, 0, 255))
    result = CliRunner().invoke(rig, ["detect", str(tmp_path), "--detector", "yolo-pose", "--model",
                                      str(models["gated"]), "--batch-size", "2"])
    assert result.exit_code == 0, result.output
    for camera, size, frames in [("cam_a", WIDE, 5), ("cam_b", TALL, 3)]:
        coco = read_coco_keypoints(tmp_path / "pose" / f"{camera}.json")
        want_kp, _ = _expected(size)
        assert len(coco.file_names) == frames and len(coco.keypoints) == frames * len(want_kp)
        assert np.abs(coco.keypoints[coco.ann_image == frames - 1] - want_kp).max() < 1e-3


def test_rig_detect_refuses_a_camera_where_no_one_is_found(models, tmp_path):
    from mvm.cli.rig import rig

    (tmp_path / "videos").mkdir()
    _video(tmp_path / "videos" / "cam_a.avi", 3, WIDE, (0, 0, 255))
    _video(tmp_path / "videos" / "cam_b.avi", 3, WIDE, (255, 0, 0))              # blue: the gate is shut
    result = CliRunner().invoke(rig, ["detect", str(tmp_path), "--detector", "yolo-pose", "--model",
                                      str(models["gated"])])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1, result.output
    assert "camera cam_b" in lines[0] and "no person detected in any of its 3 frames" in lines[0]
    assert (tmp_path / "pose" / "cam_a.json").is_file() and not (tmp_path / "pose" / "cam_b.json").exists()
    assert sorted(p.name for p in (tmp_path / "pose").iterdir() if not p.name.startswith("cam_a.")) == []


def test_rig_detect_refuses_an_unreadable_video_before_any_detection(models, tmp_path):
    from mvm.cli.rig import rig

    (tmp_path / "videos").mkdir()
    _video(tmp_path / "videos" / "cam_a.avi", 3, WIDE, (0, 0, 255))
    (tmp_path / "videos" / "cam_b.avi").write_bytes(b"RIFF" + b"\x00" * 100)
    result = CliRunner().invoke(rig, ["detect", str(tmp_path), "--detector", "yolo-pose", "--model",
                                      str(models["dynamic"])])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1 and "camera cam_b" in lines[0], result.output
    assert not (tmp_path / "pose").exists()


@pytest.mark.slow
def test_the_real_model_finds_what_ultralytics_finds(tmp_path):
    """The real YOLO11n-pose export on the real capture (20 frames of each of its 4 cameras)
    against Ultralytics' own detections of the same model: nearly every reference pose found,
    keypoints within a pixel or two. ``benchmarks/yolo_pose_reference.py`` runs all 400 frames."""
    import importlib.util

    from helpers import REPO, SHARED_DATA

    data = SHARED_DATA / "real_footage"
    model = data / "models" / "yolo11n-pose.onnx"
    if not model.is_file():
        pytest.skip(f"the real capture and its YOLO-pose model are absent: {data}")
    spec = importlib.util.spec_from_file_location("yolo_pose_reference", REPO / "benchmarks" / "yolo_pose_reference.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    detector = YoloPose(model)
    found, reference = {}, {}
    for camera in bench.CAMERAS:
        capture = cv2.VideoCapture(str(data / "videos" / f"{camera}.mp4"))
        frames = [capture.read()[1] for _ in range(20)]
        capture.release()
        for f, (kp, _) in enumerate(detector(frames)):
            found[camera, f] = kp
        ref = bench.by_frame(data / "pose_ultralytics" / f"{camera}.json")
        reference.update({(camera, f): ref[f] for f in range(20)})
    result = bench.compare(found, reference)
    assert result["reference_poses"] >= 100                       # 2 people in cam01 and cam02, 1 in the others
    assert result["found_share"] >= 0.98 and result["median_px"] <= 2.0, result
