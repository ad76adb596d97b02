"""Frames from a video: sample at a rate or up to a count, resize, skip blurred frames, keep
those the camera's motion calls for, and keep the mapping frame name <-> frame number <->
timestamp in ``SCENE/frames.json``.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from mvm.core.config import DEFAULT_FRAME_RATE_HZ, check_settings, setting
from mvm.core.names import natural_key
from mvm.errors import InputError
from mvm.io.checks import load_json
from mvm.io.files import atomic_write_bytes, atomic_write_json, make_dir
from mvm.io.images import count_frames, frame_count_bound, step_frames
from mvm.io.layout import FRAMES, FRAMES_INDEX
from mvm.io.outputs import writing_into
from mvm.io.paths import check_name
from mvm.io.provenance import produce
from mvm.video.camera_motion import MOTION_WIDTH, FeatureTracks, select_by_motion

log = logging.getLogger(__name__)

FRAMES_FORMAT = "mvm.frames/1"
#: The stage's name in the reasons of a rerun (:mod:`mvm.io.provenance`).
FRAMES_STAGE = "the frame extraction"


@dataclass(frozen=True)
class FrameOptions:
    """How frames are taken from a video."""

    #: Frames per second to sample; None: every frame of the video. [1/s]
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
    #: Which sharp sampled frames are kept: "motion" keeps a frame once the camera's image has
    #: moved `min_motion` since the last kept one (at least one every `max_gap_s`, at least
    #: `min_frames` in all); "all" keeps every one; "auto" is "motion", or "all" when a `rate` or
    #: `max_frames` is given. [-]
    select: str = setting("auto", choices=("auto", "motion", "all"))
    #: "motion": a frame is kept once the median shift of the corners tracked since the last
    #: kept frame reaches this fraction of the image diagonal; raising it keeps fewer frames,
    #: with a wider baseline between them. [fraction]
    min_motion: float = setting(0.03, gt=0, le=1)
    #: "motion": a frame is kept at least this often whatever the motion (a still camera, a
    #: frozen shot). [s]
    max_gap_s: float = setting(1.0, gt=0, le=3600)
    #: "motion": at least this many frames are kept; when the motion keeps fewer, the missing
    #: ones fill the longest stretches of the video left without a kept frame. [frames]
    min_frames: int = setting(24, ge=1, le=100_000)

    def __post_init__(self):
        check_settings(self)

    @property
    def rule(self) -> str:
        """The selection applied: "motion" or "all" (``select``, with "auto" resolved)."""
        if self.select != "auto":
            return self.select
        return "all" if self.rate is not None or self.max_frames is not None else "motion"


@dataclass
class FrameIndex:
    """The frames of a scene: ``names`` (files in ``frames/``), ``numbers: (F,)`` frame numbers
    in the video, ``timestamps: (F,)`` seconds, ``sharpness: (F,)``, the image ``size`` (w, h),
    the video's ``fps`` and the numbers of frames ``skipped`` as blurred; ``selection``: the rule
    that kept the frames, its settings and counts; with the "motion" rule, ``reasons[f]``: why
    frame f was kept and ``motion: (F,)`` the image motion since the frame kept before it
    (fraction of the diagonal, NaN for the first)."""

    video: str
    fps: float
    size: tuple[int, int]
    names: tuple[str, ...]
    numbers: np.ndarray
    timestamps: np.ndarray
    sharpness: np.ndarray
    skipped: tuple[int, ...] = ()
    selection: dict = field(default_factory=dict)
    reasons: tuple[str, ...] = ()
    motion: np.ndarray | None = None
    #: Why the frames were extracted by this call (None: kept, up to date). Not written.
    why: str | None = field(default=None, compare=False)

    def to_json(self) -> dict:
        frames = [{"file_name": n, "frame": int(k), "timestamp_s": round(float(t), 6), "sharpness": round(float(s), 3)}
                  for n, k, t, s in zip(self.names, self.numbers, self.timestamps, self.sharpness)]
        for entry, reason, moved in zip(frames, self.reasons, self.motion if self.motion is not None else []):
            entry["kept_for"] = reason
            entry["motion"] = None if not np.isfinite(moved) else round(float(moved), 5)
        document = {"format": FRAMES_FORMAT, "video": self.video, "fps": self.fps,
                    "width": self.size[0], "height": self.size[1], "frames": frames,
                    "skipped_blurred": [int(k) for k in self.skipped]}
        if self.selection:
            document["selection"] = self.selection
        return document


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


def decode_frames(capture, wanted: np.ndarray, width: int | None = None, video: str | Path = "a video"):
    """The frames numbered ``wanted: (F,)`` (sorted) of an opened ``cv2.VideoCapture`` of
    ``video``, one at a time: yields ``(number, image (H, W, 3) BGR)`` resized to ``width``.
    Frames in between are grabbed, not decoded; memory holds one frame whatever the video's
    length."""
    last = int(wanted[-1]) if len(wanted) else -1
    for number, image in step_frames(capture, set(wanted.tolist()).__contains__, last, video):
        yield number, _resize(image, width)


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


def _frame_count(video: Path, capture, options: FrameOptions) -> int:
    """The frames of ``video`` to sample from: with ``max_frames`` (spread over the whole video)
    those that decode, counted by a first pass that grabs them (then ``video`` is opened again);
    otherwise the header's count bounded by the file's size (:func:`mvm.io.images.frame_count_bound`),
    the frames that do not decode past the last one that does ending the video all the same."""
    if options.max_frames is None:
        return frame_count_bound(video, capture.get(cv2.CAP_PROP_FRAME_COUNT))
    counting = _open_video(video)
    try:
        return count_frames(counting, video)
    finally:
        counting.release()


def _decode_sampled(video: Path, options: FrameOptions, progress, frames_dir: Path | None = None,
                    tracks: FeatureTracks | None = None):
    """Decode the sampled frames of ``video`` (resized to ``options.width``) one at a time,
    measuring each one's sharpness, writing it into ``frames_dir`` (rule "all") or tracking
    corners through it into ``tracks`` (rule "motion", first pass) -> ``numbers (F,)``,
    ``sharpness (F,)``, the frame size (w, h) and the video's fps."""
    capture = _open_video(video)
    numbers, sharp, size = [], [], (0, 0)
    try:
        n_frames = _frame_count(video, capture, options)
        fps = float(capture.get(cv2.CAP_PROP_FPS)) or 0.0
        fps = fps if np.isfinite(fps) and 0 < fps < 10_000 else 0.0
        wanted = sample_indices(n_frames, fps, options.rate, options.max_frames)
        if frames_dir is not None:
            frames_dir.mkdir(parents=True, exist_ok=True)
        for number, image in decode_frames(capture, wanted, options.width, video):
            if frames_dir is not None:
                _write_frame(frames_dir / frame_name(number), image, options.jpeg_quality)
            if tracks is not None:
                tracks.add(image)
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


def _write_kept(video: Path, frames_dir: Path, kept: np.ndarray, options: FrameOptions, progress, done: int) -> None:
    """Rule "motion", second pass: decode the frames numbered ``kept: (K,)`` again and write them."""
    capture = _open_video(video)
    frames_dir.mkdir(parents=True, exist_ok=True)
    written = 0
    try:
        for number, image in decode_frames(capture, kept, options.width, video):
            _write_frame(frames_dir / frame_name(number), image, options.jpeg_quality)
            written += 1
            if progress:
                progress(done + written, done + len(kept))
    finally:
        capture.release()
    if written < len(kept):
        raise InputError(video, None, f"frame {int(kept[written])} could be decoded once but not twice")


def _select(video: Path, frames_dir: Path, options: FrameOptions, progress):
    """Rule "motion": measure, keep the sharp frames the camera's motion calls for, write them
    -> (kept numbers, their sharpness, the :class:`Selection`, the blurred numbers, size, fps,
    the count of candidates)."""
    tracks = FeatureTracks()
    numbers, sharp, size, fps = _decode_sampled(video, options, progress, tracks=tracks)
    usable = sharp_mask(sharp, options.blur_ratio)
    chosen = select_by_motion(tracks, usable, numbers / (fps if fps > 0 else DEFAULT_FRAME_RATE_HZ), options.min_motion,
                              options.max_gap_s, options.min_frames)
    _write_kept(video, frames_dir, numbers[chosen.kept], options, progress, len(numbers))
    return numbers[chosen.kept], sharp[chosen.kept], chosen, tuple(int(k) for k in numbers[~usable]), size, fps, \
        len(numbers)


def frame_inputs(video: str | Path) -> dict[str, Path]:
    """What the frames are made from (:mod:`mvm.io.provenance`): the video file."""
    return {Path(video).name: Path(video)}


def frame_settings(options: FrameOptions) -> dict:
    """The settings that shape the frames (:mod:`mvm.io.provenance`): ``select`` as the rule
    applied, and the motion rule's settings only when it is."""
    settings = asdict(options) | {"select": options.rule}
    if options.rule == "all":
        for name in ("min_motion", "max_gap_s", "min_frames"):
            settings.pop(name)
    return settings


def extract_frames(video: str | Path, scene: str | Path, options: FrameOptions = FrameOptions(),
                   force: bool = False, progress: Callable[[int, int], None] | None = None) -> FrameIndex:
    """Decode ``video`` into ``scene/frames/frame_NNNNN.jpg`` (NNNNN: the frame number) and
    write ``scene/frames.json`` with its record (``frames.inputs.json``: the video's hash and
    the options). Kept when the record says it was made from this video with these options,
    unless ``force``; the returned index's ``why`` says why it was made again.

    Which sampled frames are kept follows ``options.rule``: "all" decodes and writes every one
    as it comes and removes the blurred ones once the median sharpness is known; "motion"
    decodes them once to measure their sharpness and the camera's image motion
    (:mod:`mvm.video.camera_motion`), then again to write the sharp frames it keeps. Either way
    memory holds one frame (and a few kB of tracks per frame) whatever the video's length, and
    the frames of an earlier extraction that this one does not keep are removed.
    ``progress(done, total)`` is called after each decoded frame.
    """
    video, scene = Path(video), Path(scene)
    if not video.is_file():
        raise InputError(video, None, "video file not found")
    make_dir(scene)                                         # a file in the way: one line, before anything

    def make(why: str, hashed: dict) -> FrameIndex:
        log.info("%s: extracting frames: %s", scene, why)
        with writing_into(scene, [FRAMES, FRAMES_INDEX]):     # a user's frames.json or frames/: refused
            return _extract(video, scene, options, progress, why)

    index, _ = produce(scene / FRAMES_INDEX, FRAMES_STAGE, frame_inputs(video), frame_settings(options), make,
                       lambda: read_frame_index(scene), force=force,
                       made=lambda index: [scene / FRAMES / name for name in index.names])  # one deleted: redone
    return index


def _extract(video: Path, scene: Path, options: FrameOptions, progress, why: str) -> FrameIndex:
    """The body of :func:`extract_frames` once it decided to decode ``video`` (``why``): the
    frames and ``frames.json`` written (the record is :func:`~mvm.io.provenance.produce`'s)."""
    index_path = scene / FRAMES_INDEX
    frames_dir = scene / FRAMES
    rule = options.rule
    if rule == "all":
        numbers, sharp, size, fps = _decode_sampled(video, options, progress, frames_dir=frames_dir)
        keep = sharp_mask(sharp, options.blur_ratio)
        kept, skipped, sharp, chosen, candidates = numbers[keep], tuple(int(k) for k in numbers[~keep]), \
            sharp[keep], None, len(numbers)
    else:
        kept, sharp, chosen, skipped, size, fps, candidates = _select(video, frames_dir, options, progress)
    if skipped:
        log.warning("%s: %d of %d sampled frames are blurred (sharpness below %.2f × median) and "
                    "skipped: %s", video, len(skipped), candidates, options.blur_ratio, list(skipped)[:20])
    selection = {"rule": rule, "candidates": candidates, "blurred": len(skipped), "kept": len(kept)}
    if chosen is not None:
        selection.update(min_motion=options.min_motion, max_gap_s=options.max_gap_s, min_frames=options.min_frames,
                         motion_width=MOTION_WIDTH)
        log.info("%s: kept %d of %d sampled frames by camera motion", video, len(kept), candidates)
    index = FrameIndex(str(video), fps, size, tuple(frame_name(k) for k in kept), kept,
                       kept / fps if fps > 0 else kept.astype(float), sharp, skipped, selection,
                       chosen.reasons if chosen else (), chosen.motion if chosen else None, why=why)
    _remove_other_frames(frames_dir, set(index.names))
    document = index.to_json()
    document["options"] = asdict(options)
    atomic_write_json(index_path, document, pretty=True)
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
        selection = data.get("selection", {})
        index.selection = selection if isinstance(selection, dict) else {}
        if frames and all(isinstance(f, dict) and "kept_for" in f for f in frames):
            index.reasons = tuple(str(f["kept_for"]) for f in frames)
            index.motion = np.array([np.nan if f.get("motion") is None else float(f["motion"]) for f in frames])
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
    folder = scene / FRAMES
    if not folder.is_dir():
        raise InputError(folder, None, "no frames (run `mvm frames` first)")
    names = [p.name for p in folder.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png")]
    return sorted(names, key=natural_key)

