"""File names that come from inside input files, kept inside the scene directory.

A COCO ``file_name`` or a COLMAP image name names a file of the scene (``SCENE/frames/NAME``).
Such a name is never followed outside the scene: an absolute name (``/etc/passwd``,
``C:\\x``), a name whose ``..`` components climb above its folder (``../../x``), and a name
that resolves, through symbolic links, to a place outside the scene directory are refused
with an :class:`~mvm.errors.InputError` naming the input file and the field.
"""
from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mvm.errors import InputError

_DRIVE = re.compile(r"^[A-Za-z]:")
#: File types taken as videos (any case): a data set's clips, a rig's cameras.
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv", ".mts")


def videos_by_name(folder: str | Path) -> dict[str, Path]:
    """``{name: video}`` of the videos in ``folder`` (a rig's ``videos/``), each named by its file
    name without its type (``cam_01.mp4`` -> ``cam_01``), in name order; hidden files and other
    types are left out. An absent folder holds none; two videos of one name, or a video name on
    something that is not a file (a FIFO, a folder: reading it would hang or fail later) raise
    :class:`InputError`. A link to a video elsewhere is followed (videos are often kept apart)."""
    folder = Path(folder)
    if not folder.is_dir():
        return {}
    found: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if path.name.startswith(".") or path.suffix.lower() not in VIDEO_SUFFIXES:
            continue
        if not path.is_file():
            raise InputError(path, None, "named like a video but not a file (a FIFO, a folder or a broken link)")
        if path.stem in found:
            raise InputError(folder, None, f"two videos of camera {path.stem}: {found[path.stem].name} and {path.name}")
        found[path.stem] = path
    return found


def name_problem(name: str, allow_parent: bool = False) -> str | None:
    """Why ``name`` cannot name a file below a folder, or None when it can.

    Both ``/`` and ``\\`` count as separators, so a Windows name is judged the same way.
    With ``allow_parent``, a relative name may climb above its folder with ``..`` (a data set
    that names frames kept elsewhere, relative to itself); an absolute name is refused still.
    """
    if not isinstance(name, str) or not name:
        return "empty file name"
    if "\x00" in name:
        return "file name contains a NUL character"
    posix = name.replace("\\", "/")
    if posix.startswith("/") or _DRIVE.match(posix):
        return f"absolute path {name!r} is not allowed (names are relative to the scene)"
    normal = posixpath.normpath(posix)
    if not allow_parent and (normal == ".." or normal.startswith("../")):
        return f"path {name!r} leads outside the scene directory"
    if normal == ".":
        return f"{name!r} does not name a file"
    return None


def check_name(name: str, source: str | Path, field: str, allow_parent: bool = False) -> str:
    """Return ``name`` when it is a safe relative file name (:func:`name_problem`); raise
    :class:`InputError` naming ``source`` and ``field`` otherwise."""
    problem = name_problem(name, allow_parent)
    if problem:
        raise InputError(source, field, problem)
    return name


def is_within(path: str | Path, root: str | Path) -> bool:
    """Whether ``path``, with every symbolic link resolved, lies inside ``root`` (resolved too)."""
    resolved = Path(path).resolve()
    base = Path(root).resolve()
    return resolved == base or base in resolved.parents


def resolve_in(root: str | Path, name: str, source: str | Path, field: str,
               scene: str | Path | None = None) -> Path:
    """The path of file ``name`` below folder ``root``, refusing names and links that lead out.

    ``scene`` (default ``root``) is the directory nothing may leave: a name is checked with
    :func:`check_name`, then the joined path, symbolic links resolved, must stay inside
    ``scene``. The file need not exist. Raises :class:`InputError` (``source``, ``field``).
    """
    check_name(name, source, field)
    path = Path(root) / name.replace("\\", "/")
    if not is_within(path, root if scene is None else scene):
        raise InputError(source, field, f"{name!r} leads outside the scene directory "
                                        "through a symbolic link")
    return path
