"""2D poses of every frame and their appearance -> ``SCENE/poses2d.json`` (docs/architecture.md).

Detectors (one interface, :func:`detect_scene`; :data:`DETECTORS`): ``rtmo``, ``rtmpose``,
``yolo-pose`` and ``mvm`` (:mod:`mvm.video.detectors`), or ``import``: detections made elsewhere
(:mod:`mvm.video.importers`: OpenPifPaf, OpenPose, a COCO results file whose ``image_id`` is a
frame's file name or its 1-based position in the scene's frame list, a COCO keypoints file).

For the ONNX detectors (RTM, YOLO-pose) and imported detections the appearance is the colour descriptor of the
frame (:mod:`mvm.video.appearance`). Keypoints are the 17 COCO keypoints in frame pixels.
``poses2d.json`` records under ``info`` the detector, its model files and their SHA-256.
A frame that cannot be read is reported and left out; the others are detected.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from mvm.core.config import check_settings, setting
from mvm.core.keypoints import NUM_JOINTS
from mvm.errors import InputError
from mvm.io.coco import coco_keypoints_document, read_coco_keypoints
from mvm.io.files import atomic_write_json
from mvm.io.images import UndecodableImage, read_image
from mvm.io.layout import FRAMES, FRAMES_INDEX, POSES2D, SPARSE
from mvm.io.paths import resolve_in
from mvm.io.pose_format import pose_format
from mvm.io.provenance import produce, read_record
from mvm.video.appearance import colour_descriptor
from mvm.video.detectors import FrameDetector, check_models, make_detector
from mvm.video.frames import list_frames, read_frame_index
from mvm.video.importers import check_detections_fit, import_detections
from mvm.video.models import MODES
from mvm.video.rtm import RtmOptions
from mvm.video.yolo_pose import YoloPoseOptions

log = logging.getLogger(__name__)

#: The stage's name in the reasons of a rerun (:mod:`mvm.io.provenance`).
DETECT_STAGE = "the detection"
APPEARANCE = ("auto", "colour", "network", "none")
DETECTORS = ("rtmo", "rtmpose", "yolo-pose", "mvm", "import")
DEVICES = ("cpu", "cuda")


@dataclass(frozen=True)
class DetectOptions:
    """2D detection."""

    #: One of :data:`DETECTORS`; None: "import" when detections are given, "mvm" when a
    #: checkpoint is. [name]
    detector: str | None = setting(None, choices=DETECTORS)
    #: The detector's ONNX model (.onnx or the published .zip, or a URL fetched into the cache;
    #: for "rtmpose" the keypoint model; for "yolo-pose" an Ultralytics export, required);
    #: None: the published model of ``mode``, cached on first use. [path]
    model: str | None = None
    #: The person detector of "rtmpose" (YOLOX); None: the published one of ``mode``. [path]
    person_model: str | None = None
    #: Size of the published models when no model is given; larger is slower and finds more. [name]
    mode: str = setting("balanced", choices=MODES)
    #: Frames given to the model at once; more is faster and uses more memory. [frames]
    batch_size: int = setting(4, ge=1, le=4096)
    #: Fetch a missing published model (else: an error naming what to fetch). [bool]
    download: bool = True
    #: The RTM detectors' thresholds (a table of their own: ``[detect.rtm]``). [-]
    rtm: RtmOptions = RtmOptions()
    #: The YOLO-pose detector's thresholds (a table of their own: ``[detect.yolo]``). [-]
    yolo: YoloPoseOptions = YoloPoseOptions()
    #: Appearance descriptor stored with each pose: "auto" (network features when the network
    #: runs, else colour), "colour", "network" or "none". [name]
    appearance: str = setting("auto", choices=APPEARANCE)
    #: Keypoints below this confidence are not used to sample appearance. [0-1]
    keypoint_threshold: float = setting(0.2, ge=0, le=1)
    #: Poses with a lower score are dropped; raising it drops more false poses and more real
    #: ones. [0-1]
    min_score: float = setting(0.0, ge=0, le=1)
    #: Poses with fewer keypoints above ``keypoint_threshold`` are dropped. [keypoints]
    min_keypoints: int = setting(3, ge=0, le=17)
    #: The mvm network's input (longer side); larger finds smaller people and costs the
    #: square of it. None: the size the network was trained at (its checkpoint's JSON). [px]
    input_size: int | None = setting(None, ge=16, le=4096)
    #: Where the detector runs: "cpu" or "cuda" (torch for "mvm", ONNX Runtime for the RTM and
    #: YOLO-pose detectors). [name]
    device: str = setting("cpu", choices=DEVICES)

    def __post_init__(self):
        check_settings(self)


@dataclass
class FramePoses:
    """The 2D poses detected in the frames ``names``: ``keypoints: (N, 17, 3)``, ``image: (N,)``
    index into ``names``, ``score: (N,)``, ``appearance: (N, D)`` or None, ``sizes: (I, 2)``;
    ``source`` says what produced them, ``skipped`` the frames that could not be read."""

    names: tuple[str, ...]
    sizes: np.ndarray
    keypoints: np.ndarray
    image: np.ndarray
    score: np.ndarray
    appearance: np.ndarray | None = None
    source: str = ""
    skipped: tuple[str, ...] = ()
    #: Why the poses were made by this call (None: kept, up to date).
    why: str | None = field(default=None, compare=False)


# --------------------------------------------------------------------------- the stage


def registered_names(scene: Path) -> set[str] | None:
    """Image names in ``scene/sparse`` (None when there is no model yet)."""
    sparse = scene / SPARSE
    if not sparse.is_dir():
        return None
    import pycolmap

    from mvm.io.colmap import find_model_dir

    model_dir = find_model_dir(sparse)
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as e:  # pycolmap raises several types with C++ context
        raise InputError(model_dir, None,
                         f"cannot read COLMAP model: {str(e).splitlines()[0] if str(e) else e}") from None
    return {image.name for image in rec.images.values() if image.has_pose}


def _frame_names(scene: Path, registered: set[str] | None) -> list[str]:
    names = list_frames(scene) if (scene / FRAMES_INDEX).is_file() or (scene / FRAMES).is_dir() else []
    if not names and registered is not None:
        names = sorted(registered)
    if not names:
        raise InputError(scene, None, "no frames and no camera model: nothing to detect in")
    return names


def read_frames(scene: Path, names: list[str], batch_size: int, warn: bool = True):
    """The frames ``names`` of ``scene`` in batches: yields ``(indices into names, images)``,
    an image ``(H, W, 3)`` BGR, or None for a frame that cannot be read (reported when ``warn``)."""
    indices, images = [], []
    for i, name in enumerate(names):
        file = resolve_in(scene / FRAMES, name, scene / FRAMES_INDEX, f"frames[{i}].file_name", scene=scene)
        try:
            image = read_image(file, root=scene, missing_ok=True)
        except UndecodableImage:
            image = None
        if image is None and warn:
            log.warning("%s: cannot read this frame image; it is skipped", file)
        indices.append(i)
        images.append(image)
        if len(indices) == batch_size or i == len(names) - 1:
            yield indices, images
            indices, images = [], []


@dataclass
class _Found:
    """Detections gathered frame by frame (lists of per-frame arrays)."""

    keypoints: list
    image: list
    score: list
    appearance: list
    sizes: np.ndarray
    readable: np.ndarray

    def add(self, i: int, kp, sc, app) -> None:
        self.keypoints.append(np.asarray(kp, float).reshape(-1, NUM_JOINTS, 3))
        self.score.append(np.asarray(sc, float).reshape(-1))
        self.image.append(np.full(len(self.keypoints[-1]), i, dtype=np.int64))
        self.appearance.append(app)

    def resize(self, frames: int) -> None:
        """Hold ``frames`` frames (a video's header may count wrong): new ones readable, size 0."""
        n = min(frames, len(self.sizes))
        sizes, readable = np.zeros((frames, 2)), np.ones(frames, dtype=bool)
        sizes[:n], readable[:n] = self.sizes[:n], self.readable[:n]
        self.sizes, self.readable = sizes, readable

    def arrays(self):
        """``keypoints (N, 17, 3)``, ``image (N,)``, ``score (N,)``, ``appearance (N, D)`` or None."""
        kp = np.concatenate(self.keypoints) if self.keypoints else np.zeros((0, NUM_JOINTS, 3))
        image = np.concatenate(self.image) if self.image else np.zeros(0, np.int64)
        score = np.concatenate(self.score) if self.score else np.zeros(0)
        apps = [a for a, k in zip(self.appearance, self.keypoints) if len(k)]
        if any(a is None for a in apps) or not self.appearance:
            return kp, image, score, None
        dim = max((a.shape[1] for a in apps), default=0)
        return kp, image, score, (np.concatenate(apps) if apps else np.zeros((0, dim)))


def _appearance_of(frame: np.ndarray, kp: np.ndarray, app, options: DetectOptions):
    if options.appearance == "none":
        return None
    if options.appearance == "colour" or (app is None and options.appearance == "auto"):
        return colour_descriptor(frame, kp, options.keypoint_threshold)
    return app


def _detect_frames(scene: Path, names: list[str], detector: FrameDetector | None, imported, options: DetectOptions,
                   progress) -> _Found:
    """Run ``detector`` on every frame (or attach the appearance to ``imported`` poses)."""
    need_images = detector is not None or options.appearance != "none"
    batches = read_frames(scene, names, options.batch_size if detector else 1, warn=need_images)
    return detect_batches(batches, len(names), detector, options, progress, imported)


def detect_batches(batches, total: int, detector: FrameDetector | None, options: DetectOptions, progress=None,
                   imported=None) -> _Found:
    """The 2D poses of frames given in ``batches`` (``(indices (frame positions), images)``,
    an image ``(H, W, 3)`` BGR or None where unreadable), ``total`` frames in all: ``detector``
    on each batch (or ``imported`` poses with their appearance), each pose's appearance as
    ``options`` say. Only the batch in hand is in memory; frames past ``total`` (a video's
    header that counts wrong) are taken too, the result then holding more rows than frames
    (:meth:`_Found.resize` to the frames read). ``progress(done, total)`` before the first batch
    and after each."""
    found = _Found([], [], [], [], np.zeros((total, 2)), np.ones(total, dtype=bool))
    need_images = detector is not None or options.appearance != "none"
    done = 0
    if progress:
        progress(0, total)                           # the bar shows before the first batch is done
    for indices, images in batches:
        if indices and indices[-1] >= len(found.sizes):              # doubled: a long video costs linear time
            found.resize(max(indices[-1] + 1, 2 * len(found.sizes)))
        ok = [k for k, image in enumerate(images) if image is not None or not need_images]
        for k, image in enumerate(images):
            if image is not None:
                found.sizes[indices[k]] = image.shape[1], image.shape[0]
            elif need_images:
                found.readable[indices[k]] = False
        if detector is not None:
            results = detector.run([images[k] for k in ok]) if ok else []
        else:
            results = [_imported_in(imported, indices[k]) for k in ok]
        for k, (kp, sc, app) in zip(ok, results):
            kp = np.asarray(kp, float).reshape(-1, NUM_JOINTS, 3)
            found.add(indices[k], kp, sc, _appearance_of(images[k], kp, app, options) if need_images else None)
        done += len(indices)
        if progress:
            progress(done, max(total, done))
    return found


def _imported_in(imported, i: int):
    keypoints, image, score = imported
    rows = image == i
    return keypoints[rows], score[rows], None


def _keep(found: _Found, names: list[str], registered: set[str] | None, options: DetectOptions, scene: Path):
    """Drop weak poses and frames that are unreadable or not registered -> the kept frame names,
    sizes and ``keypoints, image, score, appearance``."""
    keypoints, image, score, appearance = found.arrays()
    keep = (score >= options.min_score) & ((keypoints[:, :, 2] >= options.keypoint_threshold).sum(1)
                                           >= options.min_keypoints)
    frames = found.readable.copy()
    if registered is not None:
        in_model = np.array([n in registered for n in names], dtype=bool)
        dropped = int((~in_model[image] & keep).sum())
        if dropped:
            log.warning("%s: %d 2D poses are in frames without a camera (not registered) and are left out",
                        scene, dropped)
        frames &= in_model
    keep &= frames[image]
    remap = np.cumsum(frames) - 1
    appearance = None if appearance is None or appearance.shape[1] == 0 else appearance[keep]
    return ([n for n, ok in zip(names, frames) if ok], found.sizes[frames], keypoints[keep], remap[image[keep]],
            score[keep], appearance)


def detect_inputs(scene: Path, registered: set[str] | None, source=None, checkpoint=None) -> dict:
    """What the 2D poses are made from (:mod:`mvm.io.provenance`): the frames, their index, the
    names of the frames that have a camera, and the imported detections or the network's
    checkpoint."""
    inputs = {FRAMES_INDEX: scene / FRAMES_INDEX, FRAMES: scene / FRAMES,
              "registered frames": sorted(registered) if registered is not None else None}
    if source is not None:
        inputs["detections"] = Path(source)
    if checkpoint is not None:
        inputs["checkpoint"] = Path(checkpoint)
    return inputs


def detect_settings(kind: str, fmt: str | None, options: DetectOptions) -> dict:
    """The settings that shape the 2D poses (:mod:`mvm.io.provenance`): the options but those
    saying how the detector runs (batch size, device), the detector and the import's format."""
    settings = asdict(options)
    for how in ("batch_size", "device", "download"):                 # how it runs, not what it finds
        settings.pop(how)
    return {**settings, "detector": kind, "format": fmt}


def _frame_size(scene: Path, names: list[str]) -> tuple[int, int] | None:
    """The frames' size (w, h): from ``frames.json``, else the first readable frame; None when unknown."""
    if (scene / FRAMES_INDEX).is_file():
        return read_frame_index(scene).size
    for _, images in read_frames(scene, names[:5], 1, warn=False):
        if images[0] is not None:
            return images[0].shape[1], images[0].shape[0]
    return None


def detect_scene(scene: str | Path, source: str | Path | None = None, checkpoint: str | Path | None = None,
                 fmt: str | None = None, options: DetectOptions = DetectOptions(), force: bool = False,
                 progress: Callable[[int, int], None] | None = None) -> FramePoses:
    """2D poses and appearance of every frame of ``scene``, written to ``scene/poses2d.json``.

    The detector is ``options.detector``: ``rtmo`` / ``rtmpose`` / ``yolo-pose`` (ONNX models), ``mvm`` (the
    network, ``checkpoint``) or ``import`` (``source``, in format ``fmt``); when None, the one
    that ``source`` or ``checkpoint`` implies. Frames that SfM did not register (when
    ``scene/sparse`` exists) and frames that cannot be read are left out.

    Kept when the record of ``poses2d.json`` (``poses2d.inputs.json``) says it was made from
    these frames, cameras, detections (or checkpoint) and settings, unless ``force``; the result's
    ``why`` says why it was made again. A ``poses2d.json`` mvm did not make is never replaced
    without ``force``. Checked before any frame is read: the detector's model files (each
    named with its option), imported detections that name no frame or were made on frames of
    another size. ``progress(done, total)`` after each batch.
    """
    scene = Path(scene)
    out = scene / POSES2D
    kind = detector_kind(options, source, checkpoint)
    if kind == "import":
        fmt = fmt or pose_format(source)[0]
    else:
        check_models(replace(options, detector=kind), checkpoint)
    if out.is_file() and not force and read_record(out) is None:
        raise InputError(out, None, "2D poses mvm did not make (no record of their inputs): give --force to replace "
                                    "them")
    registered = registered_names(scene)

    def keep() -> FramePoses:
        coco = read_coco_keypoints(out)
        return FramePoses(coco.file_names, coco.sizes, coco.keypoints, coco.ann_image, coco.score, coco.appearance,
                          "existing")

    poses, _ = produce(out, DETECT_STAGE, detect_inputs(scene, registered, source, checkpoint),
                       detect_settings(kind, fmt, options),
                       lambda why, hashed: _detect(scene, registered, kind, source, checkpoint, fmt, options, why,
                                                   progress), keep, force=force)
    return poses


def _detect(scene: Path, registered: set[str] | None, kind: str, source, checkpoint, fmt: str | None,
            options: DetectOptions, why: str, progress) -> FramePoses:
    """The body of :func:`detect_scene` once it decided to detect (``why``): ``poses2d.json``
    written (the record is :func:`~mvm.io.provenance.produce`'s)."""
    log.info("%s: detecting 2D poses: %s", scene, why)
    names = _frame_names(scene, registered)
    if kind == "import":
        imported = import_detections(source, scene, names, fmt)
        if not len(imported[0]):
            raise InputError(source, None, f"no detection is of a frame of {scene} (its frames are named like "
                                           f"{names[0]}): nothing to reconstruct")
        size = _frame_size(scene, names)
        if size is not None:
            check_detections_fit(imported[0], size, source)
        detector, info = None, {"detector": "import", "format": fmt, "file": str(source)}
    else:
        imported, detector = None, make_detector(replace(options, detector=kind), checkpoint)
        info = detector.info
    found = _detect_frames(scene, names, detector, imported, options, progress)
    skipped = tuple(n for n, ok in zip(names, found.readable) if not ok)
    if skipped:
        log.warning("%s: %d frames could not be read and were skipped (e.g. %s)", scene, len(skipped), skipped[0])
    poses, document = poses_document(found, names, registered, options, kind, info, skipped, scene)
    atomic_write_json(scene / POSES2D, document)
    return replace(poses, why=why)


def poses_document(found: _Found, names: list[str], registered: set[str] | None, options: DetectOptions, kind: str,
                   info: dict, skipped: tuple[str, ...], where: Path) -> tuple[FramePoses, dict]:
    """The poses :func:`detect_batches` ``found`` in the frames ``names``, weak ones and
    unreadable or unregistered frames left out, as :class:`FramePoses` and as the COCO keypoints
    document to write, whose ``info`` records the detector (``info``), the appearance and the
    ``skipped`` frames."""
    names, sizes, keypoints, image, score, appearance = _keep(found, names, registered, options, where)
    label = _label(info)
    info = {"source": label, **info, "appearance": _appearance_kind(appearance, kind, options),
            "skipped_frames": list(skipped)}
    document = coco_keypoints_document(names, sizes, image, keypoints, score, None, appearance)
    document["info"] = info
    return FramePoses(tuple(names), sizes, keypoints, image, score, appearance, label, skipped), document


def detector_kind(options: DetectOptions, source, checkpoint) -> str:
    """The detector that runs: ``options.detector``, else the one ``source`` (``import``) or
    ``checkpoint`` (``mvm``) implies; a contradiction raises ``ValueError``."""
    kind = options.detector or ("import" if source is not None else "mvm" if checkpoint is not None else None)
    if kind is None:
        raise ValueError("no detector: name one (rtmo, rtmpose, yolo-pose, mvm) or give detections to import")
    if (kind == "import") != (source is not None):
        raise ValueError("detections to import (source) go with the import detector only")
    if (kind == "mvm") != (checkpoint is not None):
        raise ValueError("a checkpoint goes with the mvm detector only")
    if kind != "mvm" and options.appearance == "network":
        raise ValueError(f"appearance 'network' needs the mvm network, not the {kind} detector")
    return kind


def _label(info: dict) -> str:
    if info["detector"] == "import":
        return f"import:{info['format']}:{info['file']}"
    return f"{info['detector']}:{'+'.join(m['file'] for m in info['models'])}"


def _appearance_kind(appearance, kind: str, options: DetectOptions) -> str:
    if appearance is None:
        return "none"
    return "network" if kind == "mvm" and options.appearance != "colour" else "colour"
