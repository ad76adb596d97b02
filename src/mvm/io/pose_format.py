"""What a file or folder of 2D poses holds: the one rule for imported detections
(``mvm detect --import``) and for the cameras of a rig directory.

- a file: a COCO results list (``coco-results``, :mod:`mvm.io.coco_results`) when its JSON
  starts with ``[``, else a COCO keypoints data set (``coco``, :mod:`mvm.io.coco`), whose
  reader names any problem;
- a folder: one JSON file per frame (:func:`mvm.io.openpose.frame_files`: the frame number in
  each name), in the format of the first: an object with ``people`` is OpenPose
  (:mod:`mvm.io.openpose`), a list OpenPifPaf predictions (:mod:`mvm.io.openpifpaf`).
"""
from __future__ import annotations

from pathlib import Path

from mvm.errors import InputError
from mvm.io.checks import check_input_file, load_json
from mvm.io.openpose import frame_files

POSE_FORMATS = ("coco-results", "coco", "openpifpaf", "openpose")

_BLANK = b" \t\r\n\xef\xbb\xbf"                      # JSON white space, and a UTF-8 byte order mark


def pose_format(path: str | Path, root: str | Path | None = None) -> tuple[str, list[tuple[int, Path]]]:
    """The format of the 2D poses at ``path`` (one of :data:`POSE_FORMATS`) and, for a folder,
    its per-frame files ``[(frame number, path)]`` sorted by number (none for a file). Files
    are read the guarded way, inside ``root`` when given. A folder without ``*.json`` files, or
    whose first file is neither OpenPose nor OpenPifPaf, raises :class:`InputError`."""
    path = Path(path)
    if path.is_dir():
        files = frame_files(path, "*.json")
        if not files:
            raise InputError(path, None, "no .json pose files")
        first = files[0][1]
        data = load_json(first, root)
        if isinstance(data, dict) and "people" in data:
            return "openpose", files
        if isinstance(data, list):
            return "openpifpaf", files
        raise InputError(first, None, "neither OpenPose ('people') nor OpenPifPaf (a list of predictions)")
    if not (path.exists() or path.is_symlink()):
        raise InputError(path, None, "file or directory not found")
    check_input_file(path, root)
    with open(path, "rb") as f:
        head = f.read(4096).lstrip(_BLANK)
    return ("coco-results" if head.startswith(b"[") else "coco"), []
