"""2D poses of every frame and their appearance -> ``SCENE/poses2d.json`` (docs/architecture.md).

Sources (one interface, :func:`detect_scene`):

- the project's PifPaf-style network from a local checkpoint (``mvm.net``), whose features
  give the appearance (pooled along the limbs);
- imported detections: OpenPifPaf ``--json-output`` files (one per image), OpenPose JSON
  (BODY_25, COCO-18; one per frame), a COCO results JSON (a list of
  ``{"image_id", "category_id", "keypoints", "score"}``; ``image_id`` a frame's file name, or
  its 1-based position in the scene's frame list) or a COCO keypoints dataset file.

For imported detections the appearance is the colour descriptor of the frame
(:mod:`mvm.video.appearance`). Keypoints are the 17 COCO keypoints in frame pixels.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from mvm.core.keypoints import NUM_JOINTS
from mvm.errors import InputError
from mvm.io.coco import coco_keypoints_document, parse_keypoints, read_coco_keypoints
from mvm.io.files import atomic_write_json
from mvm.io.paths import resolve_in
from mvm.video.appearance import colour_descriptor, pool_features
from mvm.video.frames import FRAMES_DIR, FRAMES_INDEX, list_frames, read_frame_index

log = logging.getLogger(__name__)

POSES2D = "poses2d.json"
FORMATS = ("coco-results", "coco", "openpifpaf", "openpose")
APPEARANCE = ("auto", "colour", "network", "none")


@dataclass(frozen=True)
class DetectOptions:
    """2D detection.

    Attributes:
        appearance: ``auto`` (network features when the network runs, else colour), ``colour``,
            ``network`` or ``none``.
        keypoint_threshold: keypoints below this confidence are not used to sample appearance. [0-1]
        min_score: poses with a lower score are dropped. [0-1]
        min_keypoints: poses with fewer keypoints above ``keypoint_threshold`` are dropped. [1]
        input_size: the network's input (longer side) in pixels. [px]
        device: torch device of the network (``cpu``, ``cuda``).
    """

    appearance: str = "auto"
    keypoint_threshold: float = 0.2
    min_score: float = 0.0
    min_keypoints: int = 3
    input_size: int = 641
    device: str = "cpu"


@dataclass
class Detections:
    """Poses of the frames ``names``: ``keypoints: (N, 17, 3)``, ``image: (N,)`` index into
    ``names``, ``score: (N,)``, ``appearance: (N, D)`` or None, ``sizes: (I, 2)``."""

    names: tuple[str, ...]
    sizes: np.ndarray
    keypoints: np.ndarray
    image: np.ndarray
    score: np.ndarray
    appearance: np.ndarray | None = None
    source: str = ""


# --------------------------------------------------------------------------- importers


def detect_format(path: str | Path) -> str:
    """Guess the format of an import source: one of :data:`FORMATS`."""
    path = Path(path)
    if path.is_dir():
        if any(path.glob("*.predictions.json")):
            return "openpifpaf"
        if any(path.glob("*_keypoints.json")):
            return "openpose"
        first = next(iter(sorted(path.glob("*.json"))), None)
        if first is None:
            raise InputError(path, None, "no JSON files to import")
        try:
            data = json.loads(first.read_text())
        except (OSError, json.JSONDecodeError, UnicodeDecodeError) as e:
            raise InputError(first, None, f"not valid JSON: {e}") from None
        return "openpose" if isinstance(data, dict) and "people" in data else "openpifpaf"
    if not path.is_file():
        raise InputError(path, None, "file or directory not found")
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(path, None, f"not valid JSON: {e}") from None
    if isinstance(data, list):
        return "coco-results"
    if isinstance(data, dict) and "annotations" in data:
        return "coco"
    raise InputError(path, None, "expected a COCO results list or a COCO keypoints dataset")


def _frame_numbers(scene: Path, names: list[str]) -> dict[int, int]:
    """Frame number -> index into ``names`` (numbers from frames.json, else from the names)."""
    from mvm.io.openpose import frame_number

    if (scene / FRAMES_INDEX).is_file():
        index = read_frame_index(scene)
        number_of = dict(zip(index.names, index.numbers.tolist()))
        return {int(number_of[n]): i for i, n in enumerate(names) if n in number_of}
    return {frame_number(n): i for i, n in enumerate(names)}


def _from_per_frame(per_frame: dict, numbers: dict[int, int], source: Path):
    keypoints, image, score = [], [], []
    unknown = sorted(set(per_frame) - set(numbers))
    if unknown:
        log.warning("%s: detections for %d frames not in the scene are ignored (e.g. frame %d)",
                    source, len(unknown), unknown[0])
    for number, value in per_frame.items():
        if number not in numbers:
            continue
        kp, sc = value if isinstance(value, tuple) else (value, None)
        if sc is None:
            present = kp[:, :, 2] > 0
            sc = np.where(present, kp[:, :, 2], 0).sum(1) / np.maximum(present.sum(1), 1)
        keypoints.append(kp)
        score.append(sc)
        image.append(np.full(len(kp), numbers[number]))
    return (np.concatenate(keypoints) if keypoints else np.zeros((0, NUM_JOINTS, 3)),
            np.concatenate(image).astype(np.int64) if image else np.zeros(0, np.int64),
            np.concatenate(score) if score else np.zeros(0))


def read_coco_results(path: str | Path, names: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A COCO results JSON -> ``keypoints: (N, 17, 3)``, ``image: (N,)`` index into ``names``,
    ``score: (N,)``. ``image_id`` is a file name (or its stem), or a 1-based position."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(path, None, f"not valid JSON: {e}") from None
    if not isinstance(data, list):
        raise InputError(path, None, "expected a JSON list of results")
    by_name = {n: i for i, n in enumerate(names)}
    by_name.update({Path(n).stem: i for i, n in enumerate(names)})
    keypoints, image, score = [], [], []
    missing = 0
    for k, item in enumerate(data):
        field = f"[{k}]"
        if not isinstance(item, dict):
            raise InputError(path, field, "expected an object")
        if item.get("category_id", 1) != 1:
            continue
        image_id = item.get("image_id")
        if isinstance(image_id, str):
            index = by_name.get(image_id, by_name.get(Path(image_id).stem))
        elif isinstance(image_id, int) and not isinstance(image_id, bool):
            index = image_id - 1 if 1 <= image_id <= len(names) else None
        else:
            raise InputError(path, f"{field}.image_id", f"expected a file name or an integer, got {image_id!r}")
        if index is None:
            missing += 1
            continue
        kp = parse_keypoints(item.get("keypoints"), path, f"{field}.keypoints")
        s = item.get("score")
        if s is None:
            present = kp[:, 2] > 0
            s = float(kp[present, 2].mean()) if present.any() else 0.0
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not np.isfinite(s) or s < 0:
            raise InputError(path, f"{field}.score", f"expected a number >= 0, got {s!r}")
        keypoints.append(kp)
        image.append(index)
        score.append(min(float(s), 1.0))
    if missing:
        log.warning("%s: %d results name images that are not in the scene and are ignored", path, missing)
    N = len(keypoints)
    return (np.array(keypoints).reshape(N, NUM_JOINTS, 3), np.array(image, dtype=np.int64),
            np.array(score, dtype=float))


def import_detections(source: str | Path, scene: str | Path, names: list[str],
                      fmt: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read detections of the frames ``names`` of ``scene`` from ``source`` in format ``fmt``
    (guessed when None) -> ``keypoints (N, 17, 3)``, ``image (N,)``, ``score (N,)``."""
    source, scene = Path(source), Path(scene)
    fmt = fmt or detect_format(source)
    if fmt not in FORMATS:
        raise InputError(source, None, f"unknown format {fmt!r} (known: {', '.join(FORMATS)})")
    if fmt == "coco-results":
        return read_coco_results(source, names)
    if fmt == "coco":
        coco = read_coco_keypoints(source)
        by_name = {n: i for i, n in enumerate(names)}
        index = np.array([by_name.get(coco.file_names[i], -1) for i in coco.ann_image], dtype=np.int64)
        if (index < 0).any():
            log.warning("%s: %d poses are in images not in the scene and are ignored", source, int((index < 0).sum()))
        keep = index >= 0
        return coco.keypoints[keep], index[keep], coco.score[keep]
    numbers = _frame_numbers(scene, names)
    if fmt == "openpifpaf":
        from mvm.io.openpifpaf import read_openpifpaf_dir

        return _from_per_frame(read_openpifpaf_dir(source), numbers, source)
    from mvm.io.openpose import read_openpose_dir

    return _from_per_frame(read_openpose_dir(source), numbers, source)


# --------------------------------------------------------------------------- network


def _network_detector(checkpoint: str | Path, options: DetectOptions):
    """``image (H, W, 3) BGR -> (keypoints (K, 17, 3), score (K,), appearance (K, C))``: the
    network of ``mvm.net`` (imported lazily: torch is an optional dependency). The appearance
    pools the backbone's last feature map (the paper's "last conv layer") along the limbs."""
    try:
        from mvm.net.evaluate import run_model
        from mvm.net.predict import load_model
    except ImportError as e:
        raise InputError(checkpoint, None, f"the pose network (mvm.net) is not available: {e}") from None
    model, _ = load_model(checkpoint, device=options.device)
    captured = {}
    model.backbone.register_forward_hook(lambda module, inputs, output: captured.__setitem__("features", output))

    def run(image: np.ndarray):
        rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
        poses, _, scale = run_model(model, rgb, options.input_size)
        kp, score = poses.keypoints, poses.score
        features = captured["features"][0].float().cpu().numpy()          # (C, h, w) of the letterboxed input
        boxed = kp.copy()
        boxed[:, :, :2] = (kp[:, :, :2] + 0.5) * scale - 0.5
        app = pool_features(features, boxed, model.spec.stride, options.keypoint_threshold)
        return kp, score, app

    return run


# --------------------------------------------------------------------------- the stage


def _registered_names(scene: Path) -> set[str] | None:
    """Image names in ``scene/sparse`` (None when there is no model yet)."""
    sparse = scene / "sparse"
    if not sparse.is_dir():
        return None
    import pycolmap

    from mvm.io.colmap import find_model_dir

    model_dir = find_model_dir(sparse)
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as e:  # pycolmap raises several types with C++ context
        raise InputError(model_dir, None, f"cannot read COLMAP model: {str(e).splitlines()[0] if str(e) else e}") from None
    return {image.name for image in rec.images.values() if image.has_pose}


def detect_scene(scene: str | Path, source: str | Path | None = None, checkpoint: str | Path | None = None,
                 fmt: str | None = None, options: DetectOptions = DetectOptions(), force: bool = False,
                 progress: Callable[[int, int], None] | None = None) -> Detections:
    """2D poses and appearance of every frame of ``scene``, written to ``scene/poses2d.json``.

    Exactly one of ``source`` (imported detections) and ``checkpoint`` (the network) is given.
    Frames that SfM did not register (when ``scene/sparse`` exists) are left out. Skipped when
    ``poses2d.json`` exists, unless ``force``.
    """
    scene = Path(scene)
    out = scene / POSES2D
    if (source is None) == (checkpoint is None):
        raise ValueError("give exactly one of source (detections to import) and checkpoint (the network)")
    if options.appearance not in APPEARANCE:
        raise ValueError(f"appearance {options.appearance!r}: expected one of {', '.join(APPEARANCE)}")
    if out.is_file() and not force:
        log.info("%s exists: 2D poses already detected (use force to redo)", out)
        coco = read_coco_keypoints(out)
        return Detections(coco.file_names, coco.sizes, coco.keypoints, coco.ann_image, coco.score,
                          coco.appearance, "existing")
    names = list_frames(scene) if (scene / FRAMES_INDEX).is_file() or (scene / FRAMES_DIR).is_dir() else []
    registered = _registered_names(scene)
    if not names and registered is not None:
        names = sorted(registered)
    if not names:
        raise InputError(scene, None, "no frames and no camera model: nothing to detect in")
    frames_dir = scene / FRAMES_DIR
    want_colour = options.appearance in ("colour", "auto")
    if source is not None:
        if options.appearance == "network":
            raise ValueError("appearance 'network' needs the network (a checkpoint), not imported detections")
        keypoints, image, score = import_detections(source, scene, names, fmt)
        appearance = None
        detector = None
        label = f"import:{fmt or detect_format(source)}:{source}"
    else:
        detector = _network_detector(checkpoint, options)
        keypoints, image, score, appearance = [], [], [], []
        label = f"network:{checkpoint}"

    sizes = np.zeros((len(names), 2))
    colour = [] if want_colour and source is not None else None
    for i, name in enumerate(names):
        file = resolve_in(frames_dir, name, scene / FRAMES_INDEX, f"frames[{i}].file_name", scene=scene)
        frame = cv2.imread(str(file)) if file.is_file() else None
        if frame is None:
            if detector is not None or colour is not None:
                raise InputError(frames_dir / name, None, "cannot read frame image")
        else:
            sizes[i] = frame.shape[1], frame.shape[0]
        if detector is not None:
            kp, sc, app = detector(frame)
            if options.appearance == "colour" or (app is None and want_colour):
                app = colour_descriptor(frame, kp, options.keypoint_threshold)
            keypoints.append(kp)
            score.append(sc)
            image.append(np.full(len(kp), i))
            appearance.append(app)
        elif colour is not None:
            rows = np.flatnonzero(image == i)
            colour.append((rows, colour_descriptor(frame, keypoints[rows], options.keypoint_threshold)))
        if progress:
            progress(i + 1, len(names))
    if detector is not None:
        keypoints = np.concatenate(keypoints) if keypoints else np.zeros((0, NUM_JOINTS, 3))
        score = np.concatenate(score) if score else np.zeros(0)
        image = np.concatenate(image).astype(np.int64) if image else np.zeros(0, np.int64)
        appearance = (np.concatenate(appearance) if appearance and all(a is not None for a in appearance)
                      else None) if options.appearance != "none" else None
    elif colour is not None:
        dim = max((c.shape[1] for _, c in colour), default=0)
        appearance = np.zeros((len(keypoints), dim))
        for rows, desc in colour:
            appearance[rows] = desc

    keep = (score >= options.min_score) & ((keypoints[:, :, 2] >= options.keypoint_threshold).sum(1) >= options.min_keypoints)
    if registered is not None:
        in_model = np.array([n in registered for n in names], dtype=bool)
        dropped = int((~in_model[image] & keep).sum())
        if dropped:
            log.warning("%s: %d 2D poses are in frames without a camera (not registered) and are left out",
                        scene, dropped)
        keep &= in_model[image]
        kept_names = [n for n, ok in zip(names, in_model) if ok]
        remap = np.cumsum(in_model) - 1
        image, sizes, names = remap[image], sizes[in_model], kept_names
    keypoints, image, score = keypoints[keep], image[keep], score[keep]
    if appearance is not None:
        appearance = appearance[keep]
        if appearance.shape[1] == 0:
            appearance = None
    detections = Detections(tuple(names), sizes, keypoints, image, score, appearance, label)
    document = coco_keypoints_document(names, sizes, image, keypoints, score, None, appearance)
    document["info"] = {"source": label, "appearance": "none" if appearance is None else
                        ("network" if detector is not None and options.appearance != "colour" else "colour")}
    atomic_write_json(out, document)
    return detections
