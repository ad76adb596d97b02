"""Ultralytics YOLO-pose (v8, 11) ONNX exports through ONNX Runtime, with Ultralytics' pre- and
post-processing, several frames per model call where the model's batch axis is dynamic.

The export (``yolo export model=yolo11n-pose.pt format=onnx``) takes ``images (B, 3, S, S)``:
RGB in [0, 1], the frame resized to fit with its aspect ratio (``cv2.INTER_LINEAR``), centred,
padded with grey 114 (:func:`centred_letterbox`); it gives ``output0 (B, 56, N)`` before
non-maximum suppression: per candidate the box centre x, y, width and height, the person
score, then 17 × (x, y, confidence) of the COCO keypoints, all in input pixels. The input
size S (or S_h × S_w) is read from the model.

Post-processing as Ultralytics' ``non_max_suppression`` (class-agnostic: one class): the
candidates scoring above the score threshold, greedy NMS by the IoU of their boxes
(``cv2.dnn.NMSBoxes``: areas as torchvision's, no +1 pixel), then boxes and keypoints mapped
back to the frame and clipped to it. Keypoints of confidence at or below the keypoint floor
are missing (v = 0 and x = y = 0, the COCO convention of ``poses2d.json``). Ultralytics maps back with one gain and
the unrounded half padding; here the padding and the per-axis scale are those the letterbox
applied, so a keypoint lands where the model saw it (a fraction of a pixel apart).

The weights are Ultralytics' (AGPL-3.0): mvm ships none; the user exports one.
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
from mvm.video.rtm import PAD_VALUE, OnnxModel, to_coco

log = logging.getLogger(__name__)

#: Channels of a YOLO-pose output row: box centre x, y, width, height, person score, 17 × (x, y, confidence).
CHANNELS = 5 + 3 * NUM_JOINTS
#: The input size of an export whose spatial axes are dynamic (Ultralytics' default). [px]
DEFAULT_SIZE = 640


@dataclass(frozen=True)
class YoloPoseOptions:
    """Thresholds of the YOLO-pose detector (Ultralytics' defaults)."""

    #: Candidates whose person score is not above this are dropped (Ultralytics' ``conf``);
    #: lowering it finds more, partly hidden people and more false ones. [0-1]
    score_threshold: float = setting(0.25, ge=0, le=1)
    #: Non-maximum suppression: of two boxes overlapping more than this, the weaker is dropped
    #: (Ultralytics' ``iou``); lower keeps fewer overlapping people. [IoU, 0-1]
    iou_threshold: float = setting(0.7, ge=0, le=1)
    #: Keypoints of confidence at or below this are reported missing (v = 0, x = y = 0);
    #: raising it drops more uncertain joints. [0-1]
    keypoint_floor: float = setting(0.05, ge=0, le=1)

    def __post_init__(self):
        check_settings(self)


def letterbox_geometry(height: int, width: int, size: tuple[int, int]):
    """Ultralytics' ``LetterBox`` (``auto=False``, centred) of a ``height × width`` frame into
    ``size`` = (w, h): the resized frame ``(new_w, new_h)``, the padding ``(left, top, right,
    bottom)`` in input pixels, and the scale ``(sx, sy)`` = resized / frame per axis.

    >>> letterbox_geometry(1920, 1088, (640, 640))
    ((363, 640), (138, 0, 139, 0), (0.33363970..., 0.33333333...))
    """
    w_in, h_in = size
    r = min(h_in / height, w_in / width)
    new_w, new_h = int(round(width * r)), int(round(height * r))
    dw, dh = (w_in - new_w) / 2, (h_in - new_h) / 2
    left, right = int(round(dw - 0.1)), int(round(dw + 0.1))
    top, bottom = int(round(dh - 0.1)), int(round(dh + 0.1))
    return (new_w, new_h), (left, top, right, bottom), (new_w / width, new_h / height)


def centred_letterbox(images: list[np.ndarray], size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """YOLO input: ``images``: B of ``(H, W, 3)`` uint8 BGR -> ``(B, 3, h, w)`` float32 RGB in
    [0, 1] (:func:`letterbox_geometry`, grey 114 around), the ``offset (B, 2)`` (left, top) and
    the ``scale (B, 2)`` (sx, sy) that map a frame pixel ``p`` to the input ``p * scale + offset``."""
    w_in, h_in = size
    batch = np.empty((len(images), h_in, w_in, 3), np.uint8)
    offset, scale = np.zeros((len(images), 2)), np.ones((len(images), 2))
    for b, image in enumerate(images):
        (new_w, new_h), (left, top, right, bottom), scale[b] = letterbox_geometry(*image.shape[:2], size)
        if (new_w, new_h) != (image.shape[1], image.shape[0]):
            image = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_LINEAR)
        batch[b] = cv2.copyMakeBorder(image, top, bottom, left, right, cv2.BORDER_CONSTANT,
                                      value=(PAD_VALUE,) * 3)
        offset[b] = left, top
    rgb = batch[..., ::-1].transpose(0, 3, 1, 2)
    return np.multiply(rgb, np.float32(1 / 255), dtype=np.float32), offset, scale


def decode(output: np.ndarray, offset: np.ndarray, scale: np.ndarray, frame_size: tuple[int, int],
           options: YoloPoseOptions = YoloPoseOptions()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The poses of one frame from its raw output ``(56, N)``: ``keypoints (K, 17, 3)`` COCO in
    frame pixels (v = 0 and x = y = 0 at or below the keypoint floor), ``score (K,)`` and
    ``boxes (K, 4)`` x1, y1, x2, y2 in frame pixels, best first. ``offset``, ``scale`` (2,):
    the letterbox's (:func:`centred_letterbox`); ``frame_size`` = (W, H) clips the results."""
    rows = output.T[output[4] > np.asarray(options.score_threshold, output.dtype)].astype(float)      # (C, 56)
    corner = np.concatenate([rows[:, :2] - rows[:, 2:4] / 2, rows[:, 2:4]], 1)     # x1, y1, w, h
    keep = np.asarray(cv2.dnn.NMSBoxes(corner, rows[:, 4].astype(np.float32), 0.0, options.iou_threshold),
                      np.int64).reshape(-1)
    rows = rows[np.sort(keep)[np.argsort(-rows[np.sort(keep), 4], kind="stable")]]     # best first, ties in order
    boxes = np.concatenate([rows[:, :2] - rows[:, 2:4] / 2, rows[:, :2] + rows[:, 2:4] / 2], 1)
    limit = np.asarray(frame_size, float)
    boxes = np.clip((boxes.reshape(-1, 2, 2) - offset) / scale, 0, limit).reshape(-1, 4)
    kp = rows[:, 5:].reshape(-1, NUM_JOINTS, 3)
    xy = np.clip((kp[:, :, :2] - offset) / scale, 0, limit)
    floor = float(np.asarray(options.keypoint_floor, output.dtype))        # compared in the model's precision
    confidence = np.where(kp[:, :, 2] > floor, kp[:, :, 2], 0.0)
    return to_coco(xy, confidence), rows[:, 4], boxes


class YoloPose:
    """An Ultralytics YOLO-pose ONNX export: ``frames`` -> per frame ``(keypoints (K, 17, 3),
    score (K,))`` in frame pixels. A model whose input is not an image ``(B, 3, h, w)`` or whose
    output is not ``(B, 56, N)`` is refused in one :class:`InputError` line naming the file."""

    def __init__(self, model: str | Path, device: str = "cpu", options: YoloPoseOptions = YoloPoseOptions()):
        self.model = OnnxModel(model, device, (DEFAULT_SIZE, DEFAULT_SIZE), outputs=1)
        self.options = options
        out = self.model.session.get_outputs()[0]
        if len(out.shape) != 3 or (isinstance(out.shape[1], int) and out.shape[1] != CHANNELS):
            raise InputError(model, None, f"not a YOLO-pose export of 17 COCO keypoints: expected the output "
                                          f"(batch, {CHANNELS}, candidates), the model's output {out.name!r} has "
                                          f"shape {list(out.shape)}")

    @property
    def size(self) -> tuple[int, int]:
        """The model's input size (w, h) in pixels."""
        return tuple(int(s) for s in self.model.size)

    def __call__(self, frames: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
        batch, offset, scale = centred_letterbox(frames, self.size)
        output = self.model(batch)[0]
        if output.ndim != 3 or output.shape[1] != CHANNELS or len(output) != len(frames):
            raise InputError(self.model.path, None, f"expected the output ({len(frames)}, {CHANNELS}, candidates), "
                                                    f"the model gave shape {list(output.shape)}")
        found = []
        for b, frame in enumerate(frames):
            keypoints, score, _ = decode(output[b], offset[b], scale[b], (frame.shape[1], frame.shape[0]),
                                         self.options)
            found.append((keypoints, score))
        return found
