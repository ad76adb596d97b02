"""Frames of a scene read the guarded way (:func:`mvm.io.checks.read_bytes`): a regular file
inside the scene directory, of bounded size, decoded from memory by OpenCV; and the frames of a
video stepped through one at a time (:func:`step_frames`)."""
from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.checks import check_input_file, read_bytes

MAX_IMAGE_BYTES = 512 * 2 ** 20
"""The largest image file a reader decodes (bytes)."""


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


def step_frames(capture, wanted: Callable[[int], bool], last: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
    """The frames of an opened ``cv2.VideoCapture`` whose number ``wanted`` accepts, up to frame
    ``last`` (None: to the end of the video), one at a time: yields ``(number, image (H, W, 3)
    BGR)``. The frames in between are grabbed, not decoded, and memory holds one frame whatever
    the video's length; the first frame that does not decode ends the video."""
    number = 0
    while last is None or number <= last:
        if wanted(number):
            ok, image = capture.read()
            if not ok:
                return
            yield number, image
        elif not capture.grab():
            return
        number += 1
