"""2D poses of a rig's videos: ``RIG_DIR/videos/<camera>.<ext>`` -> ``RIG_DIR/pose/<camera>.json``
(``mvm rig detect``).

Each camera's video is decoded frame after frame, a batch of frames in memory at a time, and
given to the detectors of ``mvm detect`` (:mod:`mvm.video.detectors`: the same
:class:`~mvm.video.detect.DetectOptions`, models and model cache). The pose file is the COCO
keypoints file the rig reader reads (:mod:`mvm.rig.rigdir`): one image per decoded frame,
``file_name`` ``<camera>/<frame>.jpg`` (frame numbers from 0, six digits), and an ``info`` that
records the detector and, under ``video``, the video's file, frame rate, frame count and size
(``mvm rig reconstruct`` takes its frame rate from there). The rig reader does not use an
appearance descriptor, so none is computed.

Reruns: beside each pose file its record (``<camera>.inputs.json``, :mod:`mvm.io.provenance`)
holds the video's hash and the settings; only the cameras whose video or settings changed are
detected again. Every video to detect is opened and its first frame decoded before any
detection: one that does not decode is refused in one line naming the camera and the file, and
nothing is written. Each pose file is written whole (atomically) when its video is done; a
camera in whose video no person is detected gets none, and the command then ends in one line
naming it (the other cameras' files are written, and kept by a rerun).
"""
from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import cv2

from mvm.errors import InputError
from mvm.io.checks import integer, load_json
from mvm.io.files import OutputError, atomic_write_json
from mvm.io.images import frame_count_bound, over_frame_limit
from mvm.io.layout import POSE_DIR, VIDEOS
from mvm.io.paths import VIDEO_SUFFIXES, videos_by_name
from mvm.io.provenance import RECORD_SUFFIX, fingerprints, produce, read_record, why_redo
from mvm.video.detect import DetectOptions, FramePoses, detect_batches, detect_settings, poses_document
from mvm.video.detectors import FrameDetector, check_models, make_detector

log = logging.getLogger(__name__)

#: The stage's name in the reasons of a rerun (:mod:`mvm.io.provenance`).
RIG_DETECT_STAGE = "the rig detection"
#: The longest camera name (a video's file name without its type) in bytes: the temporary file of
#: its pose file's record, ``.<camera>.inputs.json.mvm-tmp-XXXXXXXX.tmp``, must fit the file
#: systems' 255 bytes. [bytes]
MAX_CAMERA_NAME_BYTES = 200
#: A video that decodes fewer frames than its header and the other cameras' announce, by more than
#: this share, ends early (:func:`ends_early`): a cut or damaged file, refused. [1]
SHORT_VIDEO_SHARE = 0.01


@dataclass(frozen=True)
class VideoInfo:
    """What a camera's video holds: ``file`` (relative to the rig folder), ``frame_rate`` in Hz
    (None: the container does not say), ``frames`` decoded (the header's count before
    decoding), ``width`` and ``height`` in pixels."""

    file: str
    frame_rate: float | None
    frames: int
    width: int
    height: int

    def to_json(self) -> dict:
        return {"file": self.file, "frame_rate": self.frame_rate, "frames": self.frames, "width": self.width,
                "height": self.height}


@dataclass
class CameraPoses:
    """One camera's 2D poses: its ``camera`` name, the pose file ``path``, the ``video``
    (:class:`VideoInfo`), the number of ``poses``, and ``why`` they were detected by this call
    (None: kept, up to date)."""

    camera: str
    path: Path
    video: VideoInfo | None
    poses: int
    why: str | None


def rig_videos(rig_dir: str | Path) -> dict[str, Path]:
    """``{camera: video}`` of ``RIG_DIR/videos``, the camera named by the video's file name
    without its type (``cam_01.mp4`` -> ``cam_01``), in name order. No folder, no video or two
    videos of one camera raise :class:`InputError`."""
    folder = Path(rig_dir) / VIDEOS
    if not folder.is_dir():
        raise InputError(folder, None, "no videos folder: put one video per camera in it, named after the camera "
                                       "(cam_01.mp4, ...)")
    found = videos_by_name(folder)
    if not found:
        raise InputError(folder, None, f"no video in it (file types {', '.join(VIDEO_SUFFIXES)})")
    for camera, video in found.items():
        if len(camera.encode()) > MAX_CAMERA_NAME_BYTES:
            raise InputError(video, None, f"a camera name of {len(camera.encode())} bytes: at most "
                                          f"{MAX_CAMERA_NAME_BYTES} (its pose file, its record and their temporary "
                                          "files are named after it)")
        if (camera + ".json").lower().endswith(RECORD_SUFFIX):    # its pose file: another camera's record
            raise InputError(video, None, f"camera {camera}: a camera name may not end in "
                                          f"{RECORD_SUFFIX.removesuffix('.json')} (mvm's records of pose files)")
    return found


def _open(video: Path, camera: str):
    capture = cv2.VideoCapture(str(video))
    if not capture.isOpened():
        capture.release()
        raise InputError(video, None, f"camera {camera}: cannot open this video (not a video, or a codec OpenCV "
                                      "lacks)")
    return capture


def probe_video(video: Path, camera: str, rig_dir: Path) -> VideoInfo:
    """Open ``video`` and decode its first frame: its header's frame rate and frame count
    (bounded by the file's size: :func:`mvm.io.images.frame_count_bound`) and the frame size.
    A video that does not open or decode raises :class:`InputError` naming ``camera`` and the
    file."""
    capture = _open(video, camera)
    try:
        ok, image = capture.read()
        if not ok or image is None:
            raise InputError(video, None, f"camera {camera}: no frame of this video decodes")
        fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
        count = frame_count_bound(video, capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
    finally:
        capture.release()
    rate = fps if math.isfinite(fps) and 0 < fps < 10_000 else None
    try:
        name = video.relative_to(rig_dir).as_posix()
    except ValueError:
        name = str(video)
    return VideoInfo(name, rate, max(count, 0), image.shape[1], image.shape[0])


def video_batches(capture, batch_size: int, decoded: list[int], video: str | Path = "a video"):
    """The frames of an opened ``cv2.VideoCapture`` of ``video`` in decode order (at most
    :data:`mvm.io.images.MAX_VIDEO_FRAMES`), ``batch_size`` at a time: yields ``(frame numbers,
    images (H, W, 3) BGR)``; ``decoded[0]`` counts the frames read. Memory holds one batch
    whatever the video's length."""
    indices, images = [], []
    while not over_frame_limit(video, decoded[0]):
        ok, image = capture.read()
        if not ok:
            break
        indices.append(decoded[0])
        images.append(image)
        decoded[0] += 1
        if len(images) == batch_size:
            yield indices, images
            indices, images = [], []
    if images:
        yield indices, images


def frame_file_name(camera: str, frame: int) -> str:
    """The ``file_name`` of ``camera``'s frame ``frame`` in its pose file (the rig reader reads
    the frame number from it)."""
    return f"{camera}/{frame:06d}.jpg"


def _inputs(video: Path, checkpoint) -> dict:
    inputs = {"video": video}
    if checkpoint is not None:
        inputs["checkpoint"] = Path(checkpoint)
    return inputs


def ends_early(decoded: int, announced: int, others: int, share: float = SHORT_VIDEO_SHARE) -> bool:
    """Whether a camera's video ended before its time: fewer frames decoded than its header
    announces, and fewer than the other cameras' videos announce, each by more than ``share``
    (a cut or damaged file). A header that lies about the count alone (billions of frames) is no
    such video when the frames that decode are as many as the others'; nor is a camera that
    started late (its header counts what it holds).

    >>> ends_early(50, 100, 100), ends_early(100, 4_294_967_295, 100), ends_early(950, 950, 1000)
    (True, False, False)
    """
    return bool(announced) and decoded < announced * (1 - share) and decoded < others * (1 - share)


def _detect_camera(camera: str, video: Path, info: VideoInfo, detector: FrameDetector, options: DetectOptions,
                   kind: str, progress) -> tuple[FramePoses, dict, VideoInfo]:
    """Detect every frame of ``camera``'s ``video`` -> the poses, the pose file's document and
    the video's :class:`VideoInfo` with the frames decoded."""
    capture = _open(video, camera)
    decoded = [0]
    try:
        batches = video_batches(capture, options.batch_size, decoded, video)
        report = (lambda done, total: progress(camera, done, total)) if progress else None
        found = detect_batches(batches, info.frames, detector, options, report)
    finally:
        capture.release()
    frames = decoded[0]
    if frames == 0:
        raise InputError(video, None, f"camera {camera}: no frame of this video decodes")
    found.resize(frames)
    info = replace(info, frames=frames)
    names = [frame_file_name(camera, f) for f in range(frames)]
    poses, document = poses_document(found, names, None, options, kind, detector.info, (), video)
    document["info"]["video"] = info.to_json()
    return poses, document, info


def _kept(camera: str, path: Path, rig_dir: Path) -> CameraPoses:
    """A pose file kept as it is: its video record and pose count, read back."""
    data = load_json(path, root=rig_dir)
    info = data.get("info", {}).get("video") if isinstance(data, dict) and isinstance(data.get("info"), dict) else None
    video = None
    if isinstance(info, dict):
        video = VideoInfo(str(info.get("file", "")), info.get("frame_rate"),
                          *(integer(info.get(k, 0), path, f"info.video.{k}") for k in ("frames", "width", "height")))
    annotations = data.get("annotations", []) if isinstance(data, dict) else []
    if not isinstance(annotations, list):
        raise InputError(path, "annotations", f"expected a list, got {type(annotations).__name__}")
    poses = len(annotations)
    return CameraPoses(camera, path, video, poses, None)


def _plan(rig_dir: Path, videos: dict[str, Path], checkpoint, settings: dict, force: bool) -> list[tuple]:
    """``(camera, video, pose file, inputs, their fingerprints, why)`` of every camera (why None:
    its pose file is up to date); a pose folder in the way, or a pose file mvm did not make
    (unless ``force``), refused in one line."""
    plan = []
    for camera, video in videos.items():
        out = rig_dir / POSE_DIR / f"{camera}.json"
        if (rig_dir / POSE_DIR / camera).is_dir():
            raise InputError(rig_dir / POSE_DIR / camera, None, f"camera {camera} already has a pose folder here; "
                                                              f"move it away to detect {video.name}")
        if out.is_file() and not force and read_record(out) is None:
            raise InputError(out, None, "2D poses mvm did not make (no record of their inputs): give --force to "
                                        "replace them")
        inputs = _inputs(video, checkpoint)
        hashed = fingerprints(inputs)
        why = "forced" if force else why_redo(out, inputs, settings, RIG_DETECT_STAGE, hashed=hashed)
        plan.append((camera, video, out, inputs, hashed, why))
    return plan


def rig_detect_reason(rig_dir: str | Path, checkpoint: str | Path | None = None,
                      options: DetectOptions = DetectOptions(detector="rtmo")) -> str | None:
    """Why :func:`detect_rig_videos` would detect a camera again, ``camera NAME: WHY`` of the
    first (None: every pose file is up to date)."""
    rig_dir = Path(rig_dir)
    plan = _plan(rig_dir, rig_videos(rig_dir), checkpoint, detect_settings(options.detector, None,
                                                                           replace(options, appearance="none")), False)
    return next((f"camera {camera}: {why}" for camera, *_, why in plan if why is not None), None)


def detect_rig_videos(rig_dir: str | Path, checkpoint: str | Path | None = None,
                      options: DetectOptions = DetectOptions(detector="rtmo"), force: bool = False,
                      progress: Callable[[str, int, int], None] | None = None) -> list[CameraPoses]:
    """Detect the 2D poses of every video of ``RIG_DIR/videos`` into ``RIG_DIR/pose/<camera>.json``.

    ``options.detector``: ``rtmo``, ``rtmpose``, ``yolo-pose`` or ``mvm`` (with ``checkpoint``). A camera is
    kept when the record of its pose file says it was made from this video with these settings,
    unless ``force``; a pose file mvm did not make (no record) is never replaced without
    ``force``. Checked before any detection: the detector's model files, every video to detect
    (it opens and its first frame decodes), pose files to replace. ``progress(camera, done,
    total)`` after each batch of frames.
    """
    rig_dir = Path(rig_dir)
    if not rig_dir.is_dir():
        raise InputError(rig_dir, None, "not a directory")
    kind = options.detector
    if kind not in ("rtmo", "rtmpose", "yolo-pose", "mvm"):
        raise ValueError(f"detector {kind!r}: expected rtmo, rtmpose, yolo-pose or mvm (a rig's own detections go in "
                         f"{POSE_DIR}/)")
    options = replace(options, appearance="none")
    check_models(options, checkpoint)
    videos = rig_videos(rig_dir)
    if (rig_dir / POSE_DIR).exists() and not (rig_dir / POSE_DIR).is_dir():
        raise OutputError(rig_dir / POSE_DIR, None, "cannot write: exists and is not a folder (the cameras' pose "
                                                    "files go in it): move it away")
    settings = detect_settings(kind, None, options)
    plan = _plan(rig_dir, videos, checkpoint, settings, force)
    probed = {camera: probe_video(video, camera, rig_dir) for camera, video, _, _, _, why in plan if why is not None}
    rates = {c: i.frame_rate for c, i in probed.items() if i.frame_rate is not None}
    if rates and max(rates.values()) > min(rates.values()) * (1 + 1e-3):
        log.warning("the videos' frame rates differ: %s; mvm rig reconstruct needs one rate (resample the videos, "
                    "or give it --frame-rate)", ", ".join(f"{c} {r:g} Hz" for c, r in rates.items()))
    kept = {camera: _kept(camera, out, rig_dir) for camera, _, out, _, _, why in plan if why is None}
    lengths = {**{c: k.video.frames for c, k in kept.items() if k.video}, **{c: i.frames for c, i in probed.items()}}
    detector = make_detector(options, checkpoint) if probed else None
    done, empty, short = [], [], []
    for camera, video, out, inputs, hashed, why in plan:
        if why is None:
            log.info("%s is up to date (made from %s with these settings)", out, video.name)
            done.append(kept[camera])
            continue
        log.info("camera %s: detecting 2D poses in %s: %s", camera, video.name, why)
        poses, document, info = _detect_camera(camera, video, probed[camera], detector, options, kind, progress)
        others = max((n for c, n in lengths.items() if c != camera), default=0)   # kept cameras' too
        if ends_early(info.frames, probed[camera].frames, others):
            short.append((camera, video, info.frames, probed[camera].frames))
            continue
        if not len(poses.keypoints):
            empty.append((camera, video, info.frames))
            continue
        produce(out, RIG_DETECT_STAGE, inputs, settings,                 # decided above, with the other cameras
                lambda why, _, out=out, document=document: atomic_write_json(out, document), None, force=True,
                hashed=hashed)
        done.append(CameraPoses(camera, out, info, len(poses.keypoints), why))
    if short:
        camera, video, frames, announced = short[0]
        others = f" (and cameras {', '.join(c for c, *_ in short[1:])})" if len(short) > 1 else ""
        raise InputError(video, None, f"camera {camera}{others}: the video ends early: {frames} of the {announced} "
                                      f"frames it announces decode, fewer than the other cameras' (a cut or damaged "
                                      f"file); no pose file written for it (re-encode or replace it, or move it out "
                                      f"of {VIDEOS}/ to go on without it)")
    if empty:
        camera, video, frames = empty[0]
        others = f" (and cameras {', '.join(c for c, _, _ in empty[1:])})" if len(empty) > 1 else ""
        raise InputError(video, None, f"camera {camera}{others}: no person detected in any of its {frames} frames, "
                                      f"no pose file written for it (another --model or lower thresholds of "
                                      f"[detect]; or move the video out of {VIDEOS}/ to go on without it)")
    return done
