"""Detectors: a frame batch in, per frame the 2D poses found (and an appearance, where the
detector gives one) out; ``info`` says what ran, for ``poses2d.json``.

- ``rtmo``: RTMO, one-stage bottom-up multi-person (:mod:`mvm.video.rtm`, ONNX Runtime);
- ``rtmpose``: a YOLOX person detector then RTMPose, top-down (same);
- ``yolo-pose``: an Ultralytics YOLO-pose ONNX export the user gives (:mod:`mvm.video.yolo_pose`;
  its weights are AGPL-3.0, none is published with mvm);
- ``mvm``: the project's PifPaf-style network from a local checkpoint (``mvm.net``, imported
  lazily: torch is an optional dependency), whose features give the appearance (pooled
  along the limbs).

The settings are :class:`mvm.video.detect.DetectOptions`.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from mvm.errors import InputError
from mvm.video.appearance import pool_features
from mvm.video.models import RTMO, RTMPOSE, YOLOX, is_url, model_problem, resolve_model, sha256, url_spec

if TYPE_CHECKING:
    from mvm.video.detect import DetectOptions


@dataclass
class FrameDetector:
    """A detector: ``run(frames)`` -> per frame ``(keypoints (K, 17, 3), score (K,),
    appearance (K, D) or None)``; ``info`` is recorded in ``poses2d.json``."""

    run: Callable[[list[np.ndarray]], list[tuple]]
    info: dict


def _model_info(path: Path, given: str | Path | None = None, url: str | None = None) -> dict:
    """What ``poses2d.json`` records of a model: the ONNX file's name and SHA-256, and where it
    came from (the path given, or the published URL)."""
    return {"file": path.name, "sha256": sha256(path), "from": str(given) if given is not None else url}


def _rtm_detector(options: DetectOptions) -> FrameDetector:
    from mvm.video.rtm import Rtmo, RtmPose

    if options.detector == "rtmo":
        spec = RTMO[options.mode]
        path = resolve_model(spec, options.model, options.download)
        model = Rtmo(path, options.device, spec.size, options.rtm)
        models = [_model_info(path, options.model, spec.url)]
    else:
        person_spec, pose_spec = YOLOX[options.mode], RTMPOSE[options.mode]
        person = resolve_model(person_spec, options.person_model, options.download, option="--person-model")
        pose = resolve_model(pose_spec, options.model, options.download)
        model = RtmPose(person, pose, options.device, person_spec.size, pose_spec.size, pose_spec.mean,
                        pose_spec.std, options.rtm)
        models = [_model_info(person, options.person_model, person_spec.url),
                  _model_info(pose, options.model, pose_spec.url)]

    def run(frames):
        return [(kp, sc, None) for kp, sc in model(frames)]

    return FrameDetector(run, {"detector": options.detector, "models": models, "device": options.device})


#: How a user makes the model of ``yolo-pose`` (named when none is given).
YOLO_EXPORT = "yolo export model=yolo11n-pose.pt format=onnx"


def _yolo_detector(options: DetectOptions) -> FrameDetector:
    """The Ultralytics YOLO-pose export ``options.model`` (a file, or a URL fetched into the cache)."""
    from mvm.video.yolo_pose import YoloPose

    if options.model is None:
        raise InputError(None, "--model", f"yolo-pose needs an Ultralytics YOLO-pose ONNX export ({YOLO_EXPORT})")
    if is_url(options.model):
        path = resolve_model(url_spec(options.model), None, options.download)
    else:
        path = resolve_model(None, options.model)
    model = YoloPose(path, options.device, options.yolo)

    def run(frames):
        return [(kp, sc, None) for kp, sc in model(frames)]

    return FrameDetector(run, {"detector": "yolo-pose", "models": [_model_info(path, options.model)],
                               "device": options.device, "input_size": list(model.size)})


def _network_detector(checkpoint: str | Path, options: DetectOptions) -> FrameDetector:
    """The network of ``mvm.net`` (imported lazily: torch is an optional dependency). The
    appearance pools the backbone's last feature map (the paper's "last conv layer") along
    the limbs. The network runs at ``options.input_size``, by default the size it was trained at."""
    try:
        import torch

        from mvm.net import evaluate
        from mvm.net.predict import load_model, trained_input_size
    except ImportError as e:
        raise InputError(checkpoint, None, f"the pose network (mvm.net) is not available: {e}") from None
    model, meta = load_model(checkpoint, device=options.device)
    size = options.input_size or trained_input_size(meta, checkpoint)
    captured = {}
    model.backbone.register_forward_hook(lambda module, inputs, output: captured.__setitem__("features", output))

    def one(image: np.ndarray):
        rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
        with torch.inference_mode():                 # no autograd bookkeeping at all
            poses, _, scale = evaluate.run_model(model, rgb, size)
        kp, score = poses.keypoints, poses.score
        features = captured["features"][0].float().cpu().numpy()          # (C, h, w) of the letterboxed input
        boxed = kp.copy()
        boxed[:, :, :2] = (kp[:, :, :2] + 0.5) * scale - 0.5
        app = pool_features(features, boxed, model.spec.stride, options.keypoint_threshold)
        return kp, score, app

    info = {"detector": "mvm", "models": [_model_info(Path(checkpoint), checkpoint)], "device": options.device,
            "input_size": size}
    return FrameDetector(lambda frames: [one(f) for f in frames], info)


def check_models(options: DetectOptions, checkpoint: str | Path | None = None) -> None:
    """Check, before any work, every file the detector ``options.detector`` needs, each named
    with the option that supplies it (``rtmpose``: ``--person-model`` for the person detector
    and ``--model`` for the pose model), and its runtime: one :class:`InputError` line listing
    every problem. Reads nothing but the files' status (a second at most)."""
    import importlib.util

    problems = []
    if options.detector == "mvm":
        if checkpoint is None:
            problems.append("--checkpoint: the mvm detector needs its checkpoint")
        elif not Path(checkpoint).is_file():
            problems.append(f"--checkpoint: {checkpoint}: file not found")
        elif importlib.util.find_spec("torch") is None:
            problems.append('--detector mvm: the network needs torch: pip install "mvm[net]"')
    elif options.detector in ("rtmo", "rtmpose"):
        specs = ([(YOLOX[options.mode], options.person_model, "--person-model"),
                  (RTMPOSE[options.mode], options.model, "--model")] if options.detector == "rtmpose"
                 else [(RTMO[options.mode], options.model, "--model")])
        for spec, path, option in specs:
            problem = model_problem(spec, path, options.download, option)
            if problem is not None:
                problems.append(problem if path is None else problem.replace(f"{option}: ", f"{option} {path}: ", 1))
    elif options.detector == "yolo-pose":
        if options.model is None:
            problems.append(f"--model: yolo-pose needs an Ultralytics YOLO-pose ONNX export ({YOLO_EXPORT})")
        else:
            url = is_url(options.model)
            problem = model_problem(url_spec(options.model) if url else None, None if url else options.model,
                                    options.download)
            if problem is not None:
                problems.append(problem if url else problem.replace("--model: ", f"--model {options.model}: ", 1))
    if options.detector in ("rtmo", "rtmpose", "yolo-pose") and importlib.util.find_spec("onnxruntime") is None:
        problems.append(f'--detector {options.detector}: needs ONNX Runtime: pip install "mvm[detect]"')
    if problems:
        raise InputError(None, None, "; ".join(problems))


def fetch_missing_models(options: DetectOptions) -> None:
    """Download now the published models of ``options.detector`` that the cache lacks (when
    downloads are allowed), so that a failed download ends a run before its first heavy step."""
    from mvm.video.models import cache_path

    if not options.download:
        return
    if options.detector == "yolo-pose" and is_url(options.model):
        spec = url_spec(options.model)
        if not cache_path(spec).is_file():
            resolve_model(spec, None, True)
        return
    if options.detector not in ("rtmo", "rtmpose"):
        return
    specs = ([(YOLOX[options.mode], options.person_model, "--person-model"),
              (RTMPOSE[options.mode], options.model, "--model")] if options.detector == "rtmpose"
             else [(RTMO[options.mode], options.model, "--model")])
    for spec, path, option in specs:
        if path is None and not cache_path(spec).is_file():
            resolve_model(spec, None, True, option=option)


def make_detector(options: DetectOptions, checkpoint: str | Path | None = None) -> FrameDetector:
    """The detector ``options.detector`` (``rtmo``, ``rtmpose``, ``yolo-pose`` with
    ``options.model``, or ``mvm`` with ``checkpoint``)."""
    if options.detector == "mvm":
        if checkpoint is None:
            raise InputError(None, "--checkpoint", "the mvm detector needs its checkpoint")
        return _network_detector(checkpoint, options)
    if options.detector in ("rtmo", "rtmpose"):
        return _rtm_detector(options)
    if options.detector == "yolo-pose":
        return _yolo_detector(options)
    raise ValueError(f"detector {options.detector!r}: expected rtmo, rtmpose, yolo-pose or mvm")


def available_detector() -> str | None:
    """The detector ``mvm run`` uses when none is named: ``rtmo`` when ONNX Runtime is
    installed, else None."""
    import importlib.util

    return "rtmo" if importlib.util.find_spec("onnxruntime") is not None else None
