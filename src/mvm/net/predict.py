"""Prediction: multi-person 2D poses, relative depths and calibrated 3D from single images.

For every detected person: the 2D keypoints, each keypoint's depth relative to the person's
median depth, and metric camera coordinates ``X = s* · d · K⁻¹ [u, v, 1]`` where ``s*`` is
the length-scale calibration (bones of average adult length); the person's median depth is
then ``s*`` metres. ``K`` is a pinhole camera with the given focal length (default: the
image's long edge, about a 53° field of view) and the principal point at the centre.
"""
from __future__ import annotations

import contextlib
import logging
from pathlib import Path

import numpy as np
import torch

from mvm.core.keypoints import COCO_KEYPOINTS
from mvm.errors import InputError
from mvm.io.checks import check_input_file
from mvm.io.files import atomic_write_bytes, atomic_write_json
from mvm.io.outputs import check_names, writing_into
from mvm.net.checkpoints import read_checkpoint
from mvm.net.data import load_image
from mvm.net.decoder import DecoderConfig, normalize_depth
from mvm.net.distributed import select_device
from mvm.net.evaluate import run_model
from mvm.net.headmeta import PAF_CONNECTIONS, VIRTUAL_CONNECTIONS
from mvm.net.lift import calibrate, lift
from mvm.net.model import ModelSpec, PoseNet

LOG = logging.getLogger(__name__)
PREDICTIONS_FORMAT = "mvm.net.predictions/1"
#: The file of the predictions in the output folder.
PREDICTIONS_FILE = "predictions.json"
#: Bounds of the network input's long edge (px): the input and the backbone's first feature
#: maps grow as its square (4096 px: about 3 GB of activations on a ResNet-50; 100,000 px
#: would ask for 17 GB for the letterboxed image alone).
MIN_INPUT_SIZE, MAX_INPUT_SIZE = 16, 4096


def load_model(checkpoint: str | Path, use_ema: bool = True, device: str = "cpu") -> tuple[PoseNet, dict]:
    """Rebuild the network of a checkpoint; the EMA weights by default. -> (model in eval mode, metadata).
    A checkpoint that is not a regular file of bounded size (a FIFO, a folder) is refused unread."""
    state, meta = read_checkpoint(check_input_file(checkpoint))
    try:
        spec = ModelSpec.from_dict(meta["model"])
        model = PoseNet(spec)
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(Path(checkpoint).with_suffix(".json"), "model", f"not a valid model spec: {e}") from None
    weights = state.get("ema") if use_ema and "ema" in state else state["model"]
    try:
        model.load_state_dict(weights)
    except RuntimeError as e:
        raise InputError(checkpoint, None, f"weights do not fit {spec}: {str(e).splitlines()[0]}") from None
    return model.to(device).eval(), meta


def intrinsics(width: int, height: int, focal_px: float | None = None) -> np.ndarray:
    """Pinhole ``K (3, 3)`` with the principal point at the image centre."""
    f = float(focal_px) if focal_px else float(max(width, height))
    return np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])


def _none(a: np.ndarray, digits: int) -> list:
    return [None if not np.isfinite(v) else round(float(v), digits) for v in np.asarray(a).reshape(-1)]


def predict_image(model: PoseNet, image: np.ndarray, input_size: int, focal_px: float | None = None,
                  decoder: DecoderConfig = DecoderConfig()) -> dict:
    """People of one ``(H, W, 3)`` RGB image -> a JSON-ready dict (see :func:`predict`)."""
    H, W = image.shape[:2]
    poses, _, _ = run_model(model, image, input_size, decoder)
    K = intrinsics(W, H, focal_px)
    rel = normalize_depth(poses.depth)
    metric, s = calibrate(lift(poses.keypoints, rel, K)) if len(poses) else (np.zeros((0, 17, 3)), np.zeros(0))
    persons = []
    for p in range(len(poses)):
        persons.append({
            "score": round(float(poses.score[p]), 4),
            "keypoints": [[round(float(x), 2), round(float(y), 2), round(float(c), 4)]
                          for x, y, c in poses.keypoints[p]],
            "depth_relative": _none(rel[p], 4),
            "scale_m": None if not np.isfinite(s[p]) else round(float(s[p]), 4),
            "keypoints3d_m": [None if not np.isfinite(X).all() else [round(float(v), 4) for v in X] for X in metric[p]],
        })
    return {"width": W, "height": H, "focal_px": float(K[0, 0]), "persons": persons}


def overlay(image: np.ndarray, result: dict) -> np.ndarray:
    """Draw the skeletons of ``result`` on ``image (H, W, 3)`` RGB; joints coloured near (red) to far (blue)."""
    import cv2

    canvas = np.ascontiguousarray(image[:, :, ::-1]).copy()
    thickness = max(1, int(round(max(image.shape[:2]) / 300)))
    for person in result["persons"]:
        kp = np.array(person["keypoints"], dtype=float)
        d = np.array([np.nan if v is None else v for v in person["depth_relative"]])
        for (a, b), virtual in zip(PAF_CONNECTIONS, VIRTUAL_CONNECTIONS):
            if virtual or kp[a, 2] <= 0 or kp[b, 2] <= 0:
                continue
            cv2.line(canvas, tuple(int(round(v)) for v in kp[a, :2]), tuple(int(round(v)) for v in kp[b, :2]),
                     (255, 255, 255), thickness, cv2.LINE_AA)
        for j in np.nonzero(kp[:, 2] > 0)[0]:
            t = 0.5 if not np.isfinite(d[j]) else float(np.clip((d[j] - 0.8) / 0.4, 0, 1))
            color = (int(255 * t), 0, int(255 * (1 - t)))  # BGR: near red, far blue
            cv2.circle(canvas, tuple(int(round(v)) for v in kp[j, :2]), thickness + 1, color, -1, cv2.LINE_AA)
        if person["scale_m"] is not None and (kp[:, 2] > 0).any():
            top = kp[kp[:, 2] > 0, :2].min(0).astype(int)
            cv2.putText(canvas, f"{person['scale_m']:.1f} m", (int(top[0]), max(10, int(top[1]) - 4)),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.4 * thickness, (255, 255, 255), 1, cv2.LINE_AA)
    return canvas


def check_input_size(size, source: str | Path | None, field: str) -> int:
    """``size`` when it is a whole number of :data:`MIN_INPUT_SIZE` to :data:`MAX_INPUT_SIZE`
    px; else one :class:`InputError` line naming ``source`` and ``field``, before any memory
    is taken for it."""
    if isinstance(size, bool) or not isinstance(size, int) or not MIN_INPUT_SIZE <= size <= MAX_INPUT_SIZE:
        raise InputError(source, field, f"expected a long edge of {MIN_INPUT_SIZE} to {MAX_INPUT_SIZE} px, "
                                        f"got {size!r}")
    return size


def trained_input_size(meta: dict, checkpoint: str | Path) -> int:
    """The input size (long edge, px) the network of ``checkpoint`` was trained at, from its
    metadata ``meta`` (385 where an old checkpoint does not say), checked."""
    return check_input_size(meta.get("config", {}).get("input_size", 385), Path(checkpoint).with_suffix(".json"),
                            "config.input_size")


def predict(images: list[str | Path], checkpoint: str | Path, out_dir: str | Path | None = None,
            input_size: int | None = None, focal_px: float | None = None,
            decoder: DecoderConfig = DecoderConfig(), device: str = "auto") -> list[dict]:
    """Detect people in images with a trained checkpoint.

    Args:
        images: image files.
        checkpoint: a ``.pt`` written by :func:`mvm.net.train.train` (its ``.json`` beside it).
        out_dir: when given, writes ``predictions.json`` and ``<image stem>.overlay.jpg`` there.
        input_size: long edge of the network input (default: the training ``input_size``).
        focal_px: focal length of the images for the 3D output (default: the long edge).
        device: 'auto' (a GPU when there is one), 'cpu' or 'cuda'.
    Returns:
        one dict per image: ``{"image", "width", "height", "focal_px", "persons": [{"score",
        "keypoints" (17 × [x, y, score]), "depth_relative" (17), "scale_m",
        "keypoints3d_m" (17 × [x, y, z] camera coordinates in metres, or null)}]}``.
    """
    if not images:
        raise InputError(None, "images", "no image given")
    if input_size is not None:
        check_input_size(input_size, None, "--input-size")
    out = Path(out_dir) if out_dir is not None else None
    names = [PREDICTIONS_FILE, *(f"{Path(p).stem}.overlay.jpg" for p in images)]
    if out is not None:
        check_names(out, names)                       # a user's file there: refused before the work
    model, meta = load_model(checkpoint, device=str(select_device(device)))
    size = input_size or trained_input_size(meta, checkpoint)
    results = []
    with writing_into(out, names) if out is not None else contextlib.nullcontext():   # a user's file: refused
        for path in images:
            results.append(_predict_one(model, Path(path), size, focal_px, decoder, out))
        if out is not None:
            atomic_write_json(out / PREDICTIONS_FILE, {"format": PREDICTIONS_FORMAT, "checkpoint": str(checkpoint),
                                                       "keypoints": list(COCO_KEYPOINTS), "images": results},
                              pretty=True)
    return results


def _predict_one(model, path: Path, size: int, focal_px, decoder, out: Path | None) -> dict:
    """The prediction of one image (and its overlay written into ``out`` when given)."""
    image = load_image(path)
    with torch.no_grad():
        result = {"image": str(path), **predict_image(model, image, size, focal_px, decoder)}
    LOG.info("%s: %d people", path, len(result["persons"]))
    if out is not None:
        import cv2

        ok, buf = cv2.imencode(".jpg", overlay(image, result))
        if ok:
            atomic_write_bytes(out / f"{path.stem}.overlay.jpg", buf.tobytes())
    return result
