"""Frames of a scene read the guarded way (:func:`mvm.io.checks.read_bytes`): a regular file
inside the scene directory, of bounded size, decoded from memory by OpenCV; and the frames of a
video stepped through one at a time (:func:`step_frames`), as many as decode, never more than
:data:`MAX_VIDEO_FRAMES` (a video's header may announce any count: :func:`frame_count_bound`)."""
from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.checks import check_input_file, read_bytes

log = logging.getLogger(__name__)

MAX_IMAGE_BYTES = 512 * 2 ** 20
"""The largest image file a reader decodes (bytes)."""


def _frames_from_env() -> int:
    try:
        frames = float(os.environ.get("MVM_MAX_VIDEO_FRAMES", "2000000"))
    except ValueError:
        frames = 2e6
    return int(frames) if math.isfinite(frames) and frames >= 1 else 2_000_000


MAX_VIDEO_FRAMES = _frames_from_env()
"""The most frames read from one video (``MVM_MAX_VIDEO_FRAMES``, default 2,000,000: 18.5 hours
at 30 frames/s); the frames past it are not read, with a warning."""


class UndecodableImage(InputError):
    """A regular file inside the scene that OpenCV cannot decode: a reader of many frames may
    skip such a frame; every other refusal of :func:`read_image` stands."""


def read_image(path: str | Path, root: str | Path | None = None, flags: int | None = None,
               missing_ok: bool = False) -> np.ndarray | None:
    """The image ``path`` (inside ``root`` when given) as OpenCV decodes it, ``(H, W, 3)`` uint8
    BGR by default (``flags``: a ``cv2.IMREAD_*`` value). A file that is missing (unless
    ``missing_ok``: None), not regular, outside ``root``, too large or not an image raises
    :class:`InputError` naming it."""
    import cv2

    if missing_ok and not (Path(path).exists() or Path(path).is_symlink()):
        return None
    data = read_bytes(path, root, limit=MAX_IMAGE_BYTES)
    if not data:
        raise UndecodableImage(path, None, "empty file (0 bytes), not an image")
    try:
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR if flags is None else flags)
    except cv2.error as e:                                 # a header OpenCV rejects outright
        raise UndecodableImage(path, None, f"not an image OpenCV can decode ({_first_line(e)})") from None
    if image is None or image.size == 0:
        raise UndecodableImage(path, None, "not an image OpenCV can decode")
    return image


def _first_line(error: Exception) -> str:
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return lines[-1][:120] if lines else type(error).__name__


def check_frames(frames_dir: str | Path, names, root: str | Path) -> None:
    """Refuse (:class:`InputError`) the first of the frames ``frames_dir/NAME`` that is not a
    regular file inside ``root`` of bounded size, before a library that opens them itself
    (COLMAP's feature extraction) sees them."""
    for name in names:
        check_input_file(Path(frames_dir) / name, root, limit=MAX_IMAGE_BYTES)


def frame_count_bound(video: str | Path, announced: float) -> int:
    """How many frames ``video`` may hold, for a reader to make room for: the count its header
    ``announced`` (a forged header says anything), at most one per byte of the file and at most
    :data:`MAX_VIDEO_FRAMES`; 0 when the header says nothing usable. The frames actually there
    are those that decode (:func:`step_frames`)."""
    try:
        size = os.stat(video).st_size
    except OSError:
        size = 0
    if not math.isfinite(announced) or announced <= 0:
        return 0
    count = int(min(announced, size))
    return MAX_VIDEO_FRAMES if over_frame_limit(video, count - 1) else count


def over_frame_limit(video: str | Path, number: int) -> bool:
    """Whether frame ``number`` (from 0) of ``video`` is at or past :data:`MAX_VIDEO_FRAMES`;
    logs a warning naming the video when it is."""
    if number < MAX_VIDEO_FRAMES:
        return False
    log.warning("%s: only its first %d frames are read (MVM_MAX_VIDEO_FRAMES)", video, MAX_VIDEO_FRAMES)
    return True


def count_frames(capture, video: str | Path) -> int:
    """The frames of an opened ``cv2.VideoCapture`` counted by grabbing them (nothing converted
    or kept; at most :data:`MAX_VIDEO_FRAMES`), from where it stands to the end of ``video``."""
    number = 0
    while not over_frame_limit(video, number) and capture.grab():
        number += 1
    return number


def step_frames(capture, wanted: Callable[[int], bool], last: int | None = None,
                video: str | Path = "a video") -> Iterator[tuple[int, np.ndarray]]:
    """The frames of an opened ``cv2.VideoCapture`` whose number ``wanted`` accepts, up to frame
    ``last`` (None: to the end of ``video``) and below :data:`MAX_VIDEO_FRAMES`, one at a time:
    yields ``(number, image (H, W, 3) BGR)``. The frames in between are grabbed, not decoded,
    and memory holds one frame whatever the video's length; the first frame that does not
    decode ends the video."""
    number = 0
    while (last is None or number <= last) and not over_frame_limit(video, number):
        if wanted(number):
            ok, image = capture.read()
            if not ok:
                return
            yield number, image
        elif not capture.grab():
            return
        number += 1
