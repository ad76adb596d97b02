"""RTMO and RTMPose 2D pose detectors through ONNX Runtime, with RTMLib's pre- and
post-processing (``rtmlib.tools.pose_estimation``), several frames per model call.

- **RTMO** (one stage, bottom-up): the frame is resized to fit the 640×640 input keeping its
  aspect ratio, placed at the top left, the rest filled with grey 114; raw BGR 0-255 in.
  Outputs ``dets (B, N, 5)`` (box x1, y1, x2, y2 and score) and ``keypoints (B, N, 17, 3)``
  (x, y in input pixels and a confidence), mapped back to the frame by the resize ratio, then
  non-maximum suppression of the boxes.
- **RTMPose** (top-down): a YOLOX person detector (same letterbox input; output
  ``dets (B, N, 5)`` after its built-in NMS) gives boxes; each box, enlarged 1.25× and
  extended to the model's aspect ratio, is warped to the input (192×256 or 288×384),
  normalized by the ImageNet mean and deviation, and the SimCC outputs
  ``simcc_x (N, 17, 2W)``, ``simcc_y (N, 17, 2H)`` give each keypoint at their maxima
  (split ratio 2), with the mean of both maxima as its confidence.

As RTMLib does, images stay in OpenCV's BGR order. The keypoints are the 17 COCO keypoints
in COCO order (the Body7 models' layout); confidences are clipped to [0, 1] for COCO's ``v``,
and a keypoint of confidence 0 gets x = y = 0. The pose score is the detector's instance score.
The models' batch axis is used when it is dynamic; otherwise frames go one at a time.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from mvm.core.config import check_settings, setting
from mvm.core.keypoints import NUM_JOINTS
from mvm.errors import InputError

log = logging.getLogger(__name__)

PAD_VALUE = 114
SIMCC_SPLIT = 2.0
BOX_PADDING = 1.25

PROVIDERS = {"cpu": ["CPUExecutionProvider"], "cuda": ["CUDAExecutionProvider", "CPUExecutionProvider"]}


# --------------------------------------------------------------------------- pre-processing


def letterbox(images: list[np.ndarray], size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """RTMO / YOLOX input: each image resized to fit ``size`` = (w, h) with its aspect ratio,
    at the top left, padded with 114. ``images``: B of ``(H, W, 3)`` uint8 ->
    ``(B, 3, h, w)`` float32 and ``ratio: (B,)`` (input pixels per frame pixel)."""
    w, h = size
    batch = np.full((len(images), h, w, 3), PAD_VALUE, dtype=np.uint8)
    ratio = np.ones(len(images))
    for b, image in enumerate(images):
        if image.shape[:2] == (h, w):
            batch[b] = image
            continue
        ratio[b] = min(h / image.shape[0], w / image.shape[1])
        rw, rh = int(image.shape[1] * ratio[b]), int(image.shape[0] * ratio[b])
        batch[b, :rh, :rw] = cv2.resize(image, (rw, rh), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(batch.transpose(0, 3, 1, 2), dtype=np.float32), ratio


def box_to_input(boxes: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Top-down crop of each box: ``boxes: (N, 4)`` x1, y1, x2, y2 -> ``center: (N, 2)`` and
    ``scale: (N, 2)`` (w, h) of the frame region that fills the input ``size`` = (w, h): the box
    enlarged by 1.25 and extended to the input's aspect ratio."""
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    center = 0.5 * (boxes[:, :2] + boxes[:, 2:])
    wh = (boxes[:, 2:] - boxes[:, :2]) * BOX_PADDING
    aspect = size[0] / size[1]
    wider = wh[:, 0] > wh[:, 1] * aspect
    scale = np.where(wider[:, None], np.stack([wh[:, 0], wh[:, 0] / aspect], 1),
                     np.stack([wh[:, 1] * aspect, wh[:, 1]], 1))
    return center, scale


def crop(image: np.ndarray, center: np.ndarray, scale: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The region ``center ± scale / 2`` of ``image (H, W, 3)`` warped to ``size`` (w, h):
    ``(h, w, 3)``, same type; outside the image: 0. Only the region (and a 2-pixel margin for
    the interpolation) is read, so the cost does not grow with the frame."""
    s = size[0] / scale[0]
    H, W = image.shape[:2]
    x0 = int(np.clip(np.floor(center[0] - scale[0] / 2) - 2, 0, W))
    y0 = int(np.clip(np.floor(center[1] - scale[1] / 2) - 2, 0, H))
    x1 = int(np.clip(np.ceil(center[0] + scale[0] / 2) + 3, x0, W))
    y1 = int(np.clip(np.ceil(center[1] + scale[1] / 2) + 3, y0, H))
    if x1 - x0 < 2 or y1 - y0 < 2:
        x0, y0, x1, y1 = 0, 0, W, H
    matrix = np.array([[s, 0, size[0] / 2 - s * (center[0] - x0)], [0, s, size[1] / 2 - s * (center[1] - y0)]])
    return cv2.warpAffine(image[y0:y1, x0:x1], matrix, (int(size[0]), int(size[1])), flags=cv2.INTER_LINEAR)


def normalize(crops: np.ndarray, mean, std) -> np.ndarray:
    """``crops: (N, h, w, 3)`` -> ``(N, 3, h, w)`` float32, ``(crops - mean) / std`` per channel
    (OpenCV's blob maker: one pass, several times faster than numpy)."""
    n, h, w = crops.shape[:3]
    params = cv2.dnn.Image2BlobParams(scalefactor=tuple(1.0 / np.asarray(std, float)) + (0.0,), size=(w, h),
                                      mean=tuple(np.asarray(mean, float)) + (0.0,), swapRB=False,
                                      ddepth=cv2.CV_32F)
    return cv2.dnn.blobFromImagesWithParams(list(crops), params).reshape(n, 3, h, w)


# --------------------------------------------------------------------------- post-processing


def nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Greedy non-maximum suppression (RTMLib's, +1 pixel areas). ``boxes: (N, 4)``,
    ``scores: (N,)`` -> indices kept, best first. The IoU matrix is computed once."""
    if len(boxes) == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.argsort(-scores, kind="stable")
    b = boxes[order]
    area = (b[:, 2] - b[:, 0] + 1) * (b[:, 3] - b[:, 1] + 1)
    lo = np.maximum(b[:, None, :2], b[None, :, :2])
    hi = np.minimum(b[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.maximum(0.0, hi - lo + 1), axis=-1)
    iou = inter / (area[:, None] + area[None, :] - inter)
    alive = np.ones(len(b), dtype=bool)
    for i in range(len(b)):
        if alive[i]:
            alive[i + 1:] &= iou[i, i + 1:] <= iou_threshold
    return order[alive]


def simcc_decode(simcc_x: np.ndarray, simcc_y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """SimCC maxima: ``simcc_x: (N, K, Wx)``, ``simcc_y: (N, K, Wy)`` -> locations
    ``(N, K, 2)`` in input pixels (bins / split ratio; -1 where the response is ≤ 0) and
    confidences ``(N, K)`` (mean of both maxima)."""
    locs = np.stack([simcc_x.argmax(-1), simcc_y.argmax(-1)], -1).astype(float) / SIMCC_SPLIT
    vals = 0.5 * (simcc_x.max(-1) + simcc_y.max(-1))
    locs[vals <= 0] = -1 / SIMCC_SPLIT
    return locs, vals


def to_coco(xy: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """``xy: (N, 17, 2)`` frame pixels, ``confidence: (N, 17)`` -> COCO keypoints ``(N, 17, 3)``
    with v = confidence clipped to [0, 1]; x = y = 0 where v = 0."""
    v = np.clip(np.nan_to_num(confidence, nan=0.0), 0.0, 1.0)
    out = np.concatenate([np.where(v[..., None] > 0, xy, 0.0), v[..., None]], -1)
    if out.shape[1:] != (NUM_JOINTS, 3):
        raise ValueError(f"expected 17 COCO keypoints, the model gives {out.shape[1]}")
    return out


# --------------------------------------------------------------------------- models


def _session(model: str | Path, device: str):
    try:
        import onnxruntime as ort
    except ImportError:
        raise InputError(None, "--detector", 'ONNX Runtime is not installed: pip install "mvm[detect]"') from None
    if device not in PROVIDERS:
        raise InputError(None, "--device", f"expected one of {', '.join(PROVIDERS)}, got {device!r}")
    if device == "cuda" and "CUDAExecutionProvider" not in ort.get_available_providers():
        raise InputError(None, "--device", "cuda needs onnxruntime-gpu (pip install onnxruntime-gpu)")
    options = ort.SessionOptions()
    options.log_severity_level = 3
    try:
        return ort.InferenceSession(str(model), options, providers=PROVIDERS[device])
    except Exception as e:  # onnxruntime raises its own types for unreadable models
        raise InputError(model, None, f"cannot load the ONNX model: {str(e).splitlines()[0]}") from None


class OnnxModel:
    """An ONNX Runtime session with its input name, whether its batch axis is dynamic, and
    its input size (w, h)."""

    def __init__(self, path: str | Path, device: str, size: tuple[int, int], outputs: int):
        self.path = Path(path)
        self.session = _session(path, device)
        inp = self.session.get_inputs()[0]
        if len(inp.shape) != 4 or (isinstance(inp.shape[1], int) and inp.shape[1] != 3):
            raise InputError(path, None, f"expected an image input (batch, 3, height, width), the model's "
                                         f"input {inp.name!r} has shape {list(inp.shape)}")
        self.input = inp.name
        self.batched = not isinstance(inp.shape[0], int) or inp.shape[0] != 1
        shape = inp.shape[2:]
        self.size = (shape[1], shape[0]) if all(isinstance(d, int) for d in shape) else tuple(size)
        if len(self.session.get_outputs()) < outputs:
            raise InputError(path, None, f"expected {outputs} outputs, the model has "
                                         f"{len(self.session.get_outputs())}")

    def __call__(self, batch: np.ndarray) -> list[np.ndarray]:
        """``batch: (B, 3, h, w)`` -> the model's outputs, each with the batch axis first."""
        if self.batched or len(batch) == 1:
            return self.session.run(None, {self.input: batch})
        runs = [self.session.run(None, {self.input: batch[b:b + 1]}) for b in range(len(batch))]
        return [np.concatenate([r[k] for r in runs]) for k in range(len(runs[0]))]


@dataclass(frozen=True)
class RtmOptions:
    """Thresholds of the RTM detectors (RTMLib's defaults)."""

    #: Instances (RTMO) or person boxes (YOLOX) scoring lower are dropped; lowering it finds
    #: more, partly hidden people and more false ones. [0-1]
    score_threshold: float = setting(0.7, ge=0, le=1)
    #: Non-maximum suppression: of two boxes overlapping more than this, the weaker is dropped;
    #: lower keeps fewer overlapping people. [IoU, 0-1]
    iou_threshold: float = setting(0.45, ge=0, le=1)
    #: YOLOX person boxes scoring lower are not given to RTMPose; lowering it finds more people
    #: and more false ones. [0-1]
    person_threshold: float = setting(0.3, ge=0, le=1)

    def __post_init__(self):
        check_settings(self)


class Rtmo:
    """RTMO: ``frames`` -> per frame ``(keypoints (K, 17, 3), score (K,))`` in frame pixels."""

    def __init__(self, model: str | Path, device: str = "cpu", size=(640, 640), options: RtmOptions = RtmOptions()):
        self.model = OnnxModel(model, device, size, outputs=2)
        self.options = options

    def __call__(self, frames: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
        batch, ratio = letterbox(frames, self.model.size)
        dets, keypoints = self.model(batch)[:2]
        return [self.postprocess(dets[b], keypoints[b], ratio[b]) for b in range(len(frames))]

    def postprocess(self, dets: np.ndarray, keypoints: np.ndarray, ratio: float):
        """``dets: (N, 5)``, ``keypoints: (N, 17, 3)`` of one input -> kept poses in frame pixels."""
        boxes, scores = dets[:, :4] / ratio, dets[:, 4]
        candidates = np.flatnonzero(scores > self.options.score_threshold)
        keep = candidates[nms(boxes[candidates], scores[candidates], self.options.iou_threshold)]
        return to_coco(keypoints[keep, :, :2] / ratio, keypoints[keep, :, 2]), scores[keep].astype(float)


class RtmPose:
    """YOLOX person boxes then RTMPose keypoints: ``frames`` -> per frame
    ``(keypoints (K, 17, 3), score (K,))`` in frame pixels."""

    def __init__(self, person_model: str | Path, pose_model: str | Path, device: str = "cpu",
                 person_size=(640, 640), pose_size=(192, 256), mean=(123.675, 116.28, 103.53),
                 std=(58.395, 57.12, 57.375), options: RtmOptions = RtmOptions()):
        self.person = OnnxModel(person_model, device, person_size, outputs=1)
        self.pose = OnnxModel(pose_model, device, pose_size, outputs=2)
        self.mean, self.std, self.options = mean, std, options

    def boxes(self, frames: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
        """Person boxes of each frame: ``(boxes (N, 4) frame pixels, scores (N,))``."""
        batch, ratio = letterbox(frames, self.person.size)
        dets = self.person(batch)[0]
        if dets.ndim != 3 or dets.shape[-1] != 5:
            raise InputError(self.person.path, None, f"expected person boxes (B, N, 5) from a detector with "
                                                     f"built-in NMS, got shape {dets.shape}")
        out = []
        for b in range(len(frames)):
            keep = dets[b, :, 4] > self.options.person_threshold
            out.append((dets[b, keep, :4] / ratio[b], dets[b, keep, 4].astype(float)))
        return out

    def __call__(self, frames: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
        found = self.boxes(frames)
        crops, owner, centers, scales = [], [], [], []
        for f, (boxes, _) in enumerate(found):
            center, scale = box_to_input(boxes, self.pose.size)
            crops += [crop(frames[f], c, s, self.pose.size) for c, s in zip(center, scale)]
            owner.append(np.full(len(boxes), f))
            centers.append(center)
            scales.append(scale)
        owner = np.concatenate(owner)
        if not crops:
            return [(np.zeros((0, NUM_JOINTS, 3)), np.zeros(0)) for _ in frames]
        simcc_x, simcc_y = self.pose(normalize(np.stack(crops), self.mean, self.std))[:2]
        xy, conf = self.postprocess(simcc_x, simcc_y, np.concatenate(centers), np.concatenate(scales))
        keypoints = to_coco(xy, conf)
        return [(keypoints[owner == f], found[f][1]) for f in range(len(frames))]

    def postprocess(self, simcc_x: np.ndarray, simcc_y: np.ndarray, center: np.ndarray, scale: np.ndarray):
        """SimCC ``(N, 17, 2W)``, ``(N, 17, 2H)`` and each crop's ``center, scale: (N, 2)`` ->
        keypoints ``(N, 17, 2)`` in frame pixels and confidences ``(N, 17)``."""
        locs, vals = simcc_decode(simcc_x, simcc_y)
        xy = locs / np.asarray(self.pose.size, float) * scale[:, None] + (center - scale / 2)[:, None]
        return xy, vals
