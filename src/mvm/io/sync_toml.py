"""A rig's synchronization, ``RIG_DIR/sync.toml``::

    [offsets]              # frames to ADD to each camera's frame numbers to reach the reference's
    cam_01 = 0             # the reference camera (the first of the calibration)
    cam_02 = -3
    cam_03 = 5

    [metadata]             # how it was found (written by ``mvm rig synchronize``; optional)
    reference = "cam_01"
    method = "keypoint speed cross-correlation, triangulation error"
    ambiguous = ["cam_03"]

Camera ``c``'s frame ``f`` shows the same instant as the reference camera's frame
``f + offsets[c]``. The file must be a regular file of at most :data:`MAX_SYNC_BYTES` (a link
to nothing, a FIFO or a folder named ``sync.toml`` is refused, never taken for "no sync"), and
an offset at most :data:`MAX_OFFSET_FRAMES` frames either way (the rig reader then checks it
against the poses' frames: :func:`mvm.rig.rigdir.check_overlap`).
"""
from __future__ import annotations

import os
from pathlib import Path

from mvm.errors import InputError
from mvm.io.checks import decode_text, parse_toml, read_bytes
from mvm.io.files import atomic_write_text

#: The largest ``sync.toml`` read (bytes): a few dozen bytes a camera. [bytes]
MAX_SYNC_BYTES = 2 ** 20
#: The largest offset read, either way (more than a year of video at 30 frames/s). [frames]
MAX_OFFSET_FRAMES = 10 ** 9


def _toml_key(name: str) -> str:
    return name if name.replace("_", "").replace("-", "").isalnum() else '"' + name.replace('"', '\\"') + '"'


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return "[" + ", ".join(_toml_value(v) for v in value) + "]"


def sync_toml_text(offsets: dict[str, int], metadata: dict | None = None) -> str:
    """The text of a ``sync.toml`` (values of ``metadata``: str, numbers, booleans or lists of them)."""
    lines = ["[offsets]"] + [f"{_toml_key(n)} = {int(o)}" for n, o in offsets.items()]
    if metadata:
        lines += ["", "[metadata]"] + [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in metadata.items()]
    return "\n".join(lines) + "\n"


def write_sync_toml(path: str | Path, offsets: dict[str, int], metadata: dict | None = None) -> None:
    """Write a ``sync.toml`` atomically."""
    atomic_write_text(path, sync_toml_text(offsets, metadata))


def read_sync_toml(path: str | Path) -> dict[str, int]:
    """The ``[offsets]`` of a ``sync.toml``: ``{camera name: frames to add}``."""
    path = Path(path)
    if path.is_symlink() and not path.exists():
        raise InputError(path, None, f"a symbolic link to nothing ({os.readlink(path)}): remove it, or link the "
                                     "rig's sync.toml")
    if path.is_file() and path.stat().st_size > MAX_SYNC_BYTES:
        raise InputError(path, None, f"{path.stat().st_size:,} bytes: not a rig's offsets (at most "
                                     f"{MAX_SYNC_BYTES:,} bytes)")
    data = parse_toml(decode_text(read_bytes(path, limit=MAX_SYNC_BYTES), path), path)
    table = data.get("offsets")
    if not isinstance(table, dict) or not table:
        raise InputError(path, "[offsets]", "missing: expected one 'camera = frames' entry per camera")
    offsets = {}
    for name, value in table.items():
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(path, f"[offsets].{name}", f"expected a whole number of frames, got {value!r}")
        if abs(value) > MAX_OFFSET_FRAMES:
            raise InputError(path, f"[offsets].{name}", f"{value} frames: more than the {MAX_OFFSET_FRAMES:,} "
                                                        "frames an offset may be, either way")
        offsets[str(name)] = int(value)
    return offsets
