"""Frames from a video: sample at a rate or up to a count, resize, skip blurred frames, and
keep the mapping frame name <-> frame number <-> timestamp in ``SCENE/frames.json``.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from mvm.core.config import check_settings, setting
from mvm.errors import InputError
from mvm.io.checks import load_json
from mvm.io.files import atomic_write_bytes, atomic_write_json
from mvm.io.paths import check_name
from mvm.io.provenance import fingerprints, forget, why_redo, write_record

log = logging.getLogger(__name__)

FRAMES_DIR = "frames"
FRAMES_INDEX = "frames.json"
FRAMES_FORMAT = "mvm.frames/1"
#: The stage's name in the reasons of a rerun (:mod:`mvm.io.provenance`).
FRAMES_STAGE = "the frame extraction"


@dataclass(frozen=True)
class FrameOptions:
    """How frames are taken from a video."""

    #: Frames per second to keep; None: every frame. [1/s]
    rate: float | None = setting(None, gt=0, le=1000)
    #: Keep at most this many frames, evenly spread; None: no limit. [frames]
    max_frames: int | None = setting(None, ge=1)
    #: Resize to this width, keeping the aspect ratio; None: the original size. [px]
    width: int | None = setting(None, ge=16, le=16384)
    #: A frame whose sharpness (variance of the Laplacian) is below this fraction of the median
    #: sharpness of the sampled frames is skipped; 0 keeps all, raising it drops more
    #: motion-blurred frames. [fraction]
    blur_ratio: float = setting(0.35, ge=0, le=1)
    #: JPEG quality of the written frames; lower writes smaller, blurrier files. [0-100]
    jpeg_quality: int = setting(95, ge=1, le=100)

    def __post_init__(self):
        check_settings(self)


@dataclass
class FrameIndex:
    """The frames of a scene: ``names`` (files in ``frames/``), ``numbers: (F,)`` frame numbers
    in the video, ``timestamps: (F,)`` seconds, ``sharpness: (F,)``, the image ``size`` (w, h),
    the video's ``fps`` and the numbers of frames ``skipped`` as blurred."""

    video: str
    fps: float
    size: tuple[int, int]
    names: tuple[str, ...]
    numbers: np.ndarray
    timestamps: np.ndarray
    sharpness: np.ndarray
    skipped: tuple[int, ...] = ()
    #: Why the frames were extracted by this call (None: kept, up to date). Not written.
    why: str | None = field(default=None, compare=False)

    def to_json(self) -> dict:
        return {"format": FRAMES_FORMAT, "video": self.video, "fps": self.fps,
                "width": self.size[0], "height": self.size[1],
                "frames": [{"file_name": n, "frame": int(k), "timestamp_s": round(float(t), 6),
                            "sharpness": round(float(s), 3)}
                           for n, k, t, s in zip(self.names, self.numbers, self.timestamps, self.sharpness)],
                "skipped_blurred": [int(k) for k in self.skipped]}


def sample_indices(n_frames: int, fps: float, rate: float | None, max_frames: int | None) -> np.ndarray:
    """Frame numbers to decode: every ``fps / rate``-th frame, then at most ``max_frames``
    evenly spread. ``-> (F,)`` sorted, unique."""
    if n_frames <= 0:
        return np.zeros(0, dtype=np.int64)
    if rate is not None and rate <= 0:
        raise ValueError(f"rate must be > 0 frames per second, got {rate}")
    step = 1.0 if rate is None or fps <= 0 else max(fps / rate, 1.0)
    index = np.unique(np.round(np.arange(0, n_frames, step)).astype(np.int64))
    index = index[index < n_frames]
    if max_frames is not None and len(index) > max_frames:
        index = index[np.round(np.linspace(0, len(index) - 1, max_frames)).astype(np.int64)]
    return index


def sharpness(image: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image (higher: sharper). ``image: (H, W[, 3])``."""
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())


def sharp_mask(values: np.ndarray, ratio: float) -> np.ndarray:
    """Frames to keep: sharpness at least ``ratio`` × the median. ``values: (F,)`` -> ``(F,)`` bool."""
    values = np.asarray(values, dtype=float)
    if ratio <= 0 or len(values) == 0:
        return np.ones(len(values), dtype=bool)
    return values >= ratio * np.median(values)


def _resize(image: np.ndarray, width: int | None) -> np.ndarray:
    if width is None or width == image.shape[1]:
        return image
    height = int(round(image.shape[0] * width / image.shape[1]))
    interpolation = cv2.INTER_AREA if width < image.shape[1] else cv2.INTER_LINEAR
    return cv2.resize(image, (width, height), interpolation=interpolation)


def decode_frames(capture, wanted: np.ndarray, width: int | None = None):
    """The frames numbered ``wanted: (F,)`` (sorted) of an opened ``cv2.VideoCapture``, one at a
    time: yields ``(number, image (H, W, 3) BGR)`` resized to ``width``. Frames in between are
    grabbed, not decoded; memory holds one frame whatever the video's length."""
    wanted_set = set(wanted.tolist())
    last = wanted[-1] if len(wanted) else -1
    number = 0
    while number <= last:
        if number in wanted_set:
            ok, image = capture.read()
            if not ok:
                return
            yield number, _resize(image, width)
        elif not capture.grab():
            return
        number += 1


def frame_name(number: int) -> str:
    """The file name of frame ``number`` in ``frames/``."""
    return f"frame_{number:05d}.jpg"


def _write_frame(path: Path, image: np.ndarray, quality: int) -> None:
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError(f"cannot encode {path.name} as JPEG")
    atomic_write_bytes(path, data.tobytes())


def _open_video(video: Path):
    if not video.is_file():
        raise InputError(video, None, "video file not found")
    capture = cv2.VideoCapture(str(video))
    if not capture.isOpened():
        raise InputError(video, None, "OpenCV cannot open this video")
    return capture


def frame_size(video: str | Path, options: FrameOptions = FrameOptions()) -> tuple[int, int] | None:
    """The size (w, h) the frames of ``video`` will have with ``options``, from the video's
    header (nothing decoded); None when the header does not say."""
    capture = _open_video(Path(video))
    try:
        w, h = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
    finally:
        capture.release()
    if w <= 0 or h <= 0:
        return None
    if options.width is None or options.width == w:
        return w, h
    return options.width, int(round(h * options.width / w))


def _stream_to_disk(video: Path, frames_dir: Path, options: FrameOptions, progress):
    """Decode the sampled frames and write each at once -> ``numbers (F,)``, ``sharpness (F,)``,
    the frame size (w, h) and the video's fps."""
    capture = _open_video(video)
    numbers, sharp, size = [], [], (0, 0)
    try:
        n_frames = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = float(capture.get(cv2.CAP_PROP_FPS)) or 0.0
        wanted = sample_indices(n_frames, fps, options.rate, options.max_frames)
        frames_dir.mkdir(parents=True, exist_ok=True)
        for number, image in decode_frames(capture, wanted, options.width):
            _write_frame(frames_dir / frame_name(number), image, options.jpeg_quality)
            numbers.append(number)
            sharp.append(sharpness(image))
            size = (image.shape[1], image.shape[0])
            if progress:
                progress(len(numbers), len(wanted))
    finally:
        capture.release()
    if not numbers:
        raise InputError(video, None, "no frame could be decoded")
    return np.array(numbers, dtype=np.int64), np.array(sharp), size, fps


def frame_inputs(video: str | Path) -> dict[str, Path]:
    """What the frames are made from (:mod:`mvm.io.provenance`): the video file."""
    return {Path(video).name: Path(video)}


def _frame_settings(options: FrameOptions) -> dict:
    return asdict(options)


def frames_reason(video: str | Path, scene: str | Path, options: FrameOptions = FrameOptions(),
                  force: bool = False) -> str | None:
    """Why :func:`extract_frames` would decode ``video`` again (None: ``frames.json`` is up to
    date: made from this video's bytes with these options)."""
    if force:
        return "forced"
    return why_redo(Path(scene) / FRAMES_INDEX, frame_inputs(video), _frame_settings(options), FRAMES_STAGE)


def extract_frames(video: str | Path, scene: str | Path, options: FrameOptions = FrameOptions(),
                   force: bool = False, progress: Callable[[int, int], None] | None = None) -> FrameIndex:
    """Decode ``video`` into ``scene/frames/frame_NNNNN.jpg`` (NNNNN: the frame number) and
    write ``scene/frames.json`` with its record (``frames.inputs.json``: the video's hash and
    the options). Kept when the record says it was made from this video with these options,
    unless ``force``; the returned index's ``why`` says why it was made again.

    Frames are decoded and written one at a time (bounded memory whatever the video's length);
    blurred ones are removed once the median sharpness is known, and so are the frames of an
    earlier extraction that this one does not keep. ``progress(done, total)`` is called after
    each decoded candidate frame.
    """
    video, scene = Path(video), Path(scene)
    index_path = scene / FRAMES_INDEX
    if not video.is_file():
        raise InputError(video, None, "video file not found")
    hashed = fingerprints(frame_inputs(video))
    why = frames_reason(video, scene, options, force)
    if why is None:
        log.info("%s is up to date (made from %s with these options)", index_path, video.name)
        return read_frame_index(scene)
    log.info("%s: extracting frames: %s", scene, why)
    frames_dir = scene / FRAMES_DIR
    forget(index_path)
    numbers, sharp, size, fps = _stream_to_disk(video, frames_dir, options, progress)
    keep = sharp_mask(sharp, options.blur_ratio)
    skipped = tuple(int(k) for k in numbers[~keep])
    if skipped:
        log.warning("%s: %d of %d sampled frames are blurred (sharpness below %.2f × median) and "
                    "skipped: %s", video, len(skipped), len(numbers), options.blur_ratio, list(skipped)[:20])
    kept = numbers[keep]
    index = FrameIndex(str(video), fps, size, tuple(frame_name(k) for k in kept),
                       kept, kept / fps if fps > 0 else kept.astype(float), sharp[keep], skipped, why)
    _remove_other_frames(frames_dir, set(index.names))
    document = index.to_json()
    document["options"] = asdict(options)
    atomic_write_json(index_path, document, pretty=True)
    write_record(index_path, FRAMES_STAGE, frame_inputs(video), _frame_settings(options), hashed)
    return index


def _remove_other_frames(frames_dir: Path, keep: set[str]) -> None:
    """Delete the frame files mvm wrote (``frame_NNNNN.jpg``) that are not in ``keep``: the
    blurred frames and those of an earlier extraction with other options."""
    import re

    for path in frames_dir.glob("frame_*.jpg"):
        if path.name not in keep and re.fullmatch(r"frame_\d{5,}\.jpg", path.name):
            path.unlink(missing_ok=True)


def read_frame_index(scene: str | Path) -> FrameIndex:
    """Read ``scene/frames.json``."""
    path = Path(scene) / FRAMES_INDEX
    if not path.exists():
        raise InputError(path, None, "file not found (run `mvm frames` first)")
    data = load_json(path, root=scene)
    if not isinstance(data, dict) or data.get("format") != FRAMES_FORMAT:
        raise InputError(path, "format", f"expected {FRAMES_FORMAT!r}")
    try:
        frames = data["frames"]
        index = FrameIndex(
            data.get("video", ""), float(data.get("fps", 0.0)), (int(data["width"]), int(data["height"])),
            tuple(str(f["file_name"]) for f in frames), np.array([int(f["frame"]) for f in frames], dtype=np.int64),
            np.array([float(f["timestamp_s"]) for f in frames]),
            np.array([float(f.get("sharpness", 0)) for f in frames]),
            tuple(int(k) for k in data.get("skipped_blurred", [])))
    except (KeyError, TypeError, ValueError, OverflowError) as e:
        raise InputError(path, "frames", f"malformed entry: {e}") from None
    for i, name in enumerate(index.names):
        check_name(name, path, f"frames[{i}].file_name")
    return index


def list_frames(scene: str | Path) -> list[str]:
    """Image names of a scene: from ``frames.json`` when present, else the files of ``frames/``
    sorted by the number in their name."""
    scene = Path(scene)
    if (scene / FRAMES_INDEX).is_file():
        return list(read_frame_index(scene).names)
    folder = scene / FRAMES_DIR
    if not folder.is_dir():
        raise InputError(folder, None, "no frames (run `mvm frames` first)")
    names = [p.name for p in folder.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png")]
    return sorted(names, key=_natural_key)


def _natural_key(name: str):
    import re

    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]
