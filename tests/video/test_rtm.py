"""The RTMO / RTMPose adapter end to end on ONNX models made here with the real models' input and
output signatures: pre-processing (letterbox, BGR, top-down crop, normalization), keypoints back
to frame pixels, score handling and COCO-17, and the scene stage that records the model."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from mvm.errors import InputError
from mvm.io.coco import read_coco_keypoints
from mvm.video.detect import DetectOptions, detect_scene
from mvm.video.models import sha256

torch = pytest.importorskip("torch", reason="the test models are exported from torch")
pytest.importorskip("onnxruntime", reason="onnxruntime is the optional 'detect' extra")
pytest.importorskip("onnx", reason="torch's ONNX exporter needs the onnx package")

from mvm.video.rtm import Rtmo, RtmPose, letterbox, nms

J = 17
GREY = 60
SQUARE = 30                                     # side of the blue square in frame pixels


def _frame(h, w, x0, y0):
    """A grey BGR frame with a pure blue square (B = 255) whose top-left corner is (x0, y0)."""
    frame = np.full((h, w, 3), GREY, np.uint8)
    frame[y0:y0 + SQUARE, x0:x0 + SQUARE] = (255, 0, 0)
    return frame


def _centre(x0, y0):
    return np.array([x0 + (SQUARE - 1) / 2, y0 + (SQUARE - 1) / 2])


def _blue_centroid(x, low, high):
    """Centroid (x, y) in input pixels of the pixels whose channel 0 (blue in BGR) is in (low, high)."""
    mask = ((x[:, 0] > low) & (x[:, 0] < high)).float()                       # (B, H, W)
    H, W = x.shape[2], x.shape[3]
    ys = torch.arange(H, dtype=torch.float32).view(1, H, 1)
    xs = torch.arange(W, dtype=torch.float32).view(1, 1, W)
    n = mask.sum((1, 2))
    return (mask * xs).sum((1, 2)) / n, (mask * ys).sum((1, 2)) / n


CONF = torch.linspace(0.0, 1.2, J)             # joint 0: confidence 0 (missing); the last ones above 1


class FakeRtmo(torch.nn.Module):
    """RTMO's signature: ``input (B, 3, 640, 640)`` raw BGR -> ``dets (B, 3, 5)``,
    ``keypoints (B, 3, 17, 3)``. Instance 0 sits on the blue square, keypoint j at its centre
    + (j, 2j) input pixels; instance 1 is a near copy (NMS removes it); instance 2 scores 0.5
    (below the threshold). Joint 1's confidence is the pad value at (635, 635) / 228 = 0.5."""

    def forward(self, x):
        cx, cy = _blue_centroid(x, 200, 256)
        B = x.shape[0]
        j = torch.arange(J, dtype=torch.float32)
        kx = cx[:, None] + j[None]
        ky = cy[:, None] + 2 * j[None]
        conf = CONF[None].repeat(B, 1)
        conf = torch.cat([conf[:, :1], (x[:, 1, 635, 635] / 228)[:, None], conf[:, 2:]], 1)
        kp0 = torch.stack([kx, ky, conf], -1)                                 # (B, 17, 3)
        kp = torch.stack([kp0, kp0 + 2, kp0 + 100], 1)                        # (B, 3, 17, 3)
        box0 = torch.stack([cx - 10, cy - 10, cx + 10, cy + 10], -1)
        boxes = torch.stack([box0, box0 + 1, box0 + 100], 1)
        scores = torch.tensor([0.9, 0.8, 0.5]).view(1, 3, 1).repeat(B, 1, 1)
        return torch.cat([boxes, scores], -1), kp


class FakeYolox(torch.nn.Module):
    """YOLOX with NMS's signature: ``input (B, 3, 640, 640)`` -> ``dets (B, 2, 5)``: a box of
    ±20 input pixels around the blue square (score 0.9) and one of score 0.2 (dropped)."""

    def forward(self, x):
        cx, cy = _blue_centroid(x, 200, 256)
        box = torch.stack([cx - 20, cy - 20, cx + 20, cy + 20], -1)
        boxes = torch.stack([box, box + 50], 1)
        scores = torch.tensor([0.9, 0.2]).view(1, 2, 1).repeat(x.shape[0], 1, 1)
        return torch.cat([boxes, scores], -1)


class FakeRtmPose(torch.nn.Module):
    """RTMPose's signature: ``input (N, 3, 256, 192)`` normalized -> ``simcc_x (N, 17, 384)``,
    ``simcc_y (N, 17, 512)``: keypoint j at the blue square's centre in the crop + (4j, 3j), with
    maxima VX[j] and VY[j]. Only normalized blue (≈ 2.64) is seen as blue."""

    def forward(self, x):
        cx, cy = _blue_centroid(x, 2.0, 3.0)
        j = torch.arange(J, dtype=torch.float32)
        tx = torch.round(2 * (cx[:, None] + 4 * j[None]))                     # (N, 17) bins
        ty = torch.round(2 * (cy[:, None] + 3 * j[None]))
        kx = torch.arange(384, dtype=torch.float32).view(1, 1, -1)
        ky = torch.arange(512, dtype=torch.float32).view(1, 1, -1)
        sx = ((kx - tx[..., None]).abs() < 0.5).float() * VX.view(1, J, 1)
        sy = ((ky - ty[..., None]).abs() < 0.5).float() * VY.view(1, J, 1)
        return sx, sy


VX = torch.linspace(0.0, 1.0, J)
VY = torch.linspace(0.0, 0.6, J)


def _export(module, path, shape, outputs, dynamic=True):
    torch.onnx.export(module, (torch.zeros(shape),), str(path), input_names=["input"], output_names=outputs,
                      dynamic_axes={"input": {0: "batch"}} if dynamic else None, opset_version=17, dynamo=False)
    return path


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    import warnings

    folder = tmp_path_factory.mktemp("onnx")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {"rtmo": _export(FakeRtmo(), folder / "rtmo.onnx", (1, 3, 640, 640), ["dets", "keypoints"]),
                "rtmo1": _export(FakeRtmo(), folder / "rtmo1.onnx", (1, 3, 640, 640), ["dets", "keypoints"],
                                 dynamic=False),
                "yolox": _export(FakeYolox(), folder / "yolox.onnx", (1, 3, 640, 640), ["dets"]),
                "rtmpose": _export(FakeRtmPose(), folder / "rtmpose.onnx", (1, 3, 256, 192),
                                   ["simcc_x", "simcc_y"])}


def test_letterbox_keeps_aspect_top_left_with_grey_padding():
    frame = np.full((480, 960, 3), 7, np.uint8)
    batch, ratio = letterbox([frame], (640, 640))
    assert batch.shape == (1, 3, 640, 640) and batch.dtype == np.float32
    assert ratio[0] == pytest.approx(2 / 3)
    assert (batch[0, :, :320] == 7).all() and (batch[0, :, 320:] == 114).all()


def test_nms_keeps_the_best_of_overlapping_boxes():
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [50, 50, 60, 60], [0, 0, 10, 10.5]], float)
    scores = np.array([0.6, 0.9, 0.5, 0.1])
    assert nms(boxes, scores, 0.45).tolist() == [1, 2]


@pytest.mark.parametrize("name", ["rtmo", "rtmo1"])
def test_rtmo_maps_keypoints_to_frame_pixels(models, name):
    frames = [_frame(480, 960, 300, 150), _frame(800, 400, 100, 600)]        # two sizes, two ratios
    out = Rtmo(models[name])(frames)
    for (kp, score), (x0, y0), ratio in zip(out, [(300, 150), (100, 600)], [2 / 3, 0.8]):
        assert kp.shape == (1, J, 3) and score.tolist() == pytest.approx([0.9])   # one instance survives
        c = _centre(x0, y0)
        j = np.arange(J)
        want = np.stack([c[0] + j / ratio, c[1] + 2 * j / ratio], -1)
        assert np.abs(kp[0, 1:, :2] - want[1:]).max() < 1.5
        assert kp[0, 0].tolist() == [0, 0, 0]                                 # confidence 0: missing
        assert kp[0, 1, 2] == pytest.approx(0.5)                              # grey 114 padding seen
        assert kp[0, 2:, 2] == pytest.approx(np.clip(CONF.numpy()[2:], 0, 1), abs=1e-6)


def test_rtmpose_crops_normalizes_and_maps_back(models):
    frames = [_frame(480, 640, 200, 100), _frame(480, 640, 400, 300)]
    detector = RtmPose(models["yolox"], models["rtmpose"])
    ratio = 1.0                                                             # 640 wide: no resize
    for (kp, score), (x0, y0) in zip(detector(frames), [(200, 100), (400, 300)]):
        assert kp.shape == (1, J, 3) and score.tolist() == pytest.approx([0.9])
        box = 40 / ratio * 1.25                                             # ±20 px box, enlarged
        scale = np.array([box, box / 0.75])                                  # extended to 192:256
        c = _centre(x0, y0)
        j = np.arange(J)
        want = np.stack([c[0] + 4 * j * scale[0] / 192, c[1] + 3 * j * scale[1] / 256], -1)
        assert np.abs(kp[0, 1:, :2] - want[1:]).max() < 0.75
        assert kp[0, 1:, 2] == pytest.approx(0.5 * (VX + VY).numpy()[1:], abs=1e-6)
        assert kp[0, 0].tolist() == [0, 0, 0]


def _scene(tmp_path, frames):
    (tmp_path / "frames").mkdir()
    names = []
    for k, frame in enumerate(frames):
        names.append(f"frame_{k:05d}.jpg")
        cv2.imwrite(str(tmp_path / "frames" / names[-1]), frame)
    return names


def test_scene_stage_records_the_model_and_skips_an_unreadable_frame(models, tmp_path):
    names = _scene(tmp_path, [_frame(480, 960, 300, 150), _frame(480, 960, 500, 200), _frame(480, 960, 50, 50)])
    (tmp_path / "frames" / names[1]).write_bytes(b"not an image")
    d = detect_scene(tmp_path, options=DetectOptions(detector="rtmo", model=str(models["rtmo"]), batch_size=2))
    assert d.skipped == (names[1],) and d.names == (names[0], names[2])
    coco = read_coco_keypoints(tmp_path / "poses2d.json")
    assert coco.file_names == (names[0], names[2]) and len(coco.keypoints) == 2
    assert np.abs(coco.keypoints[1, 5, :2] - (_centre(50, 50) + np.array([5, 10]) * 1.5)).max() < 2.0
    assert coco.appearance is not None and coco.appearance.shape[0] == 2      # colour descriptor
    info = json.loads((tmp_path / "poses2d.json").read_text())["info"]
    assert info["detector"] == "rtmo" and info["skipped_frames"] == [names[1]]
    assert info["models"] == [{"file": "rtmo.onnx", "sha256": sha256(models["rtmo"]), "from": str(models["rtmo"])}]


def test_cli_detect_with_rtmpose(models, tmp_path):
    from mvm.cli.video import detect_cmd

    _scene(tmp_path, [_frame(480, 640, 200, 100)])
    result = CliRunner().invoke(detect_cmd, [str(tmp_path), "--detector", "rtmpose", "--model", str(models["rtmpose"]),
                                             "--person-model", str(models["yolox"])])
    assert result.exit_code == 0, result.output
    info = json.loads((tmp_path / "poses2d.json").read_text())["info"]
    assert info["detector"] == "rtmpose" and [m["file"] for m in info["models"]] == ["yolox.onnx", "rtmpose.onnx"]


def test_a_broken_model_is_one_line_exit_2(tmp_path):
    from mvm.cli.video import detect_cmd

    _scene(tmp_path, [_frame(100, 100, 10, 10)])
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"\x00garbage")
    result = CliRunner().invoke(detect_cmd, [str(tmp_path), "--detector", "rtmo", "--model", str(bad)])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and str(bad) in lines[0]
    assert not (tmp_path / "poses2d.json").exists()


def test_model_with_wrong_outputs_is_refused(models):
    with pytest.raises(InputError, match="expected 2 outputs"):
        Rtmo(models["yolox"])


def test_crop_reads_only_the_region_and_equals_the_whole_frame_warp():
    from mvm.video.rtm import box_to_input, crop

    rng = np.random.default_rng(1)
    image = rng.integers(0, 255, (300, 500, 3), dtype=np.uint8)
    boxes = np.array([[100.3, 50.7, 180.2, 250.1], [-40, -30, 60, 90], [450, 200, 530, 330]])
    center, scale = box_to_input(boxes, (192, 256))
    assert scale[0] == pytest.approx([max(79.9, 199.4 * 0.75) * 1.25, max(79.9 / 0.75, 199.4) * 1.25])
    for c, s in zip(center, scale):
        k = 192 / s[0]
        matrix = np.array([[k, 0, 96 - k * c[0]], [0, k, 128 - k * c[1]]])
        whole = cv2.warpAffine(image, matrix, (192, 256), flags=cv2.INTER_LINEAR)
        assert np.abs(crop(image, c, s, (192, 256)).astype(int) - whole).max() <= 1


def test_default_detector_uses_the_cached_published_model(models, tmp_path, monkeypatch):
    """No --detector: rtmo (ONNX Runtime is installed), its published model found in the cache
    (put there as the published zip), nothing downloaded."""
    import zipfile

    from mvm.cli.video import detect_cmd
    from mvm.video.models import RTMO

    monkeypatch.setenv("MVM_CACHE", str(tmp_path / "cache"))
    cached = tmp_path / "cache" / "models" / RTMO["balanced"].url.rsplit("/", 1)[-1]
    cached.parent.mkdir(parents=True)
    with zipfile.ZipFile(cached, "w") as z:
        z.write(models["rtmo"], "rtmo-m/end2end.onnx")
    scene = tmp_path / "scene"
    scene.mkdir()
    _scene(scene, [_frame(480, 960, 300, 150)])
    result = CliRunner().invoke(detect_cmd, [str(scene)])
    assert result.exit_code == 0, result.output
    info = json.loads((scene / "poses2d.json").read_text())["info"]
    assert info["detector"] == "rtmo" and info["models"][0]["file"] == "end2end.onnx"
    assert info["models"][0]["sha256"] == sha256(models["rtmo"]) and info["models"][0]["from"] == RTMO["balanced"].url


def test_without_a_detector_installed_one_line_says_what_to_install(tmp_path, monkeypatch):
    import mvm.video.detectors
    from mvm.cli.video import detect_cmd

    monkeypatch.setattr(mvm.video.detectors, "available_detector", lambda: None)
    _scene(tmp_path, [_frame(100, 100, 10, 10)])
    result = CliRunner().invoke(detect_cmd, [str(tmp_path)])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and 'pip install "mvm[detect]"' in lines[0]


def test_normalize_is_per_channel_mean_and_deviation_channels_first():
    from mvm.video.rtm import normalize

    crops = np.random.default_rng(2).integers(0, 255, (2, 8, 6, 3), dtype=np.uint8)
    mean, std = np.array([10.0, 100.0, 200.0]), np.array([1.0, 2.0, 4.0])
    want = ((crops - mean) / std).transpose(0, 3, 1, 2)
    got = normalize(crops, mean, std)
    assert got.shape == (2, 3, 8, 6) and got.dtype == np.float32
    assert np.allclose(got, want, atol=1e-5)


@pytest.mark.parametrize("shape", [[1, 10], [1, 1, 640, 640]])
def test_a_model_without_an_image_input_is_one_line(tmp_path, shape):
    import onnx
    from onnx import TensorProto, helper

    graph = helper.make_graph([helper.make_node("Identity", ["input"], ["dets"]),
                               helper.make_node("Identity", ["input"], ["keypoints"])], "g",
                              [helper.make_tensor_value_info("input", TensorProto.FLOAT, shape)],
                              [helper.make_tensor_value_info(n, TensorProto.FLOAT, shape)
                               for n in ("dets", "keypoints")])
    path = tmp_path / "flat.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8), path)
    with pytest.raises(InputError, match=r"flat\.onnx: expected an image input \(batch, 3, height, width\)"):
        Rtmo(path)
