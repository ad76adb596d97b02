"""Atomic writes: a reader never sees a half-written output file.

Every file is written to a temporary file in the same directory (``.NAME.mvm-tmp-XXXX.tmp``),
flushed and fsynced, renamed over its final name with :func:`os.replace` (atomic on POSIX
and Windows), and the directory is fsynced so that the rename survives a power loss. A
process killed at any point leaves the previous file (or none) and at most a stale
temporary file, which the next write into that folder deletes once its writer's process is gone
(:func:`sweep_dead_temporaries`, the one cleaner of temporary files). One run writes an output
at a time: :func:`mvm.io.outputs.output_lock`, the one lock.

The temporary file is created private (``0600``) by :func:`tempfile.mkstemp`; before it is
renamed into place it gets the mode a plain ``open`` would have given it, ``0666`` less the
process umask (:func:`new_file_mode`), so that outputs are as readable as the user's umask says.

Every operating-system error of a write (a read-only or immutable folder, a folder on the
way that is a file, an output name taken by a folder, a full disk) is raised as one
:class:`OutputError` line naming the path, exit status 2, and leaves no temporary file.
"""
from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import stat
import tempfile
from pathlib import Path

import orjson

from mvm.errors import InputError

#: The random part of a temporary file's or folder's name follows this: ``.NAME.mvm-tmp-k2j4h_x.tmp``.
#: Only names carrying it are removed as a killed writer's leftovers, never a user's ``.NAME.old.tmp``.
TEMPORARY_INFIX = ".mvm-tmp-"


class OutputError(InputError):
    """An output that cannot be written: one line naming the path and the reason, exit 2."""


_WRITE_PROBLEMS = {errno.ENOSPC: "no space left on the device", errno.EDQUOT: "disk quota exceeded",
                   errno.EROFS: "read-only file system", errno.EACCES: "permission denied",
                   errno.EPERM: "operation not permitted (an immutable or protected folder?)",
                   errno.EISDIR: "is a directory, expected a file",
                   errno.ENOTDIR: "a folder on the way is a file",
                   errno.EEXIST: "a file is in the way of a folder"}


def output_error(path: str | Path, error: OSError) -> OutputError:
    """The one-line :class:`OutputError` for ``error`` while writing ``path``."""
    problem = _WRITE_PROBLEMS.get(error.errno) or error.strerror or str(error)
    return OutputError(path, None, f"cannot write: {problem}")


def make_dir(path: str | Path) -> Path:
    """Create the folder ``path`` (and its parents) for outputs; an existing file in the way
    or any OS error raises :class:`OutputError` naming it."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(path, None, "cannot write: exists and is not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise output_error(path, e) from None
    return path


def process_umask() -> int:
    """The process umask, read without changing it where ``/proc`` tells it (elsewhere set and
    restored at once)."""
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def new_file_mode() -> int:
    """The mode of a new file under the process umask: ``0644`` under umask ``022``."""
    return 0o666 & ~process_umask()


def new_dir_mode() -> int:
    """The mode of a new folder under the process umask: ``0755`` under umask ``022``."""
    return 0o777 & ~process_umask()


def fsync_dir(directory: Path) -> None:
    """Make a rename in ``directory`` durable (POSIX; a no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


_NOT_A_FILE = ((stat.S_ISLNK, "is a symbolic link"), (stat.S_ISFIFO, "is a FIFO (named pipe)"),
               (stat.S_ISCHR, "is a device"), (stat.S_ISBLK, "is a device"), (stat.S_ISSOCK, "is a socket"))


def check_file_target(path: str | Path) -> None:
    """Refuse, in one :class:`OutputError` line, to put a file at ``path`` when something other
    than a regular file is there: a symbolic link (whatever it points to), a FIFO, a device, a
    socket or a folder. Nothing at ``path``, or a regular file, passes. Every file output is
    checked here before its temporary is made and again just before the rename: a device given
    as an output is never replaced by a regular file, a link never followed nor replaced."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as e:
        raise output_error(path, e) from None
    if stat.S_ISDIR(mode):
        raise OutputError(path, None, "cannot write: is a directory, expected a file")
    for test, problem in _NOT_A_FILE:
        if test(mode):
            raise OutputError(path, None, f"refusing to write: {problem}, not a regular file; "
                                          "choose another output")


@contextlib.contextmanager
def atomic_output(path: str | Path, suffix: str = ".tmp"):
    """Yield the name of a fresh temporary file beside ``path`` (``.NAME.XXXX<suffix>``) for a
    writer to fill; when the block ends cleanly it is renamed over ``path``, otherwise removed.
    Something at ``path`` that is not a regular file (a link, a FIFO, a device, a socket, a
    folder) is refused before any write (:func:`check_file_target`). Every OS error (the
    folder, the temporary file, the rename) raises :class:`OutputError`."""
    path = Path(path)
    make_dir(path.parent)
    check_file_target(path)
    sweep_dead_temporaries(path.parent)                # what a killed run of this folder left
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}{TEMPORARY_INFIX}{os.getpid()}-", suffix=suffix,
                                   dir=path.parent)
    except OSError as e:
        raise output_error(path, e) from None
    try:
        os.fchmod(fd, new_file_mode())             # mkstemp's 0600 would leak into the output
    except (OSError, AttributeError):              # no fchmod (Windows): modes do not apply
        pass
    finally:
        os.close(fd)
    try:
        yield Path(tmp)
        check_file_target(path)                    # what the writer took its time over may have changed
        os.replace(tmp, path)
    except OSError as e:
        raise output_error(path, e) from None
    finally:
        Path(tmp).unlink(missing_ok=True)
    fsync_dir(path.parent)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path``, fsync it, then rename over ``path``."""
    with atomic_output(path) as tmp:
        with os.fdopen(os.open(tmp, os.O_WRONLY | getattr(os, "O_CLOEXEC", 0)), "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def first_non_finite(obj, where: str = "") -> str | None:
    """The JSON path (e.g. ``persons[2].keypoints3d[5][0]``) of the first NaN or infinite
    number in ``obj`` (dicts, lists, tuples, numbers), or None when every number is finite."""
    if isinstance(obj, float):
        return None if math.isfinite(obj) else (where or "(root)")
    if isinstance(obj, dict):
        for key, value in obj.items():
            found = first_non_finite(value, f"{where}.{key}" if where else str(key))
            if found:
                return found
    elif isinstance(obj, (list, tuple)):
        for i, value in enumerate(obj):
            found = first_non_finite(value, f"{where}[{i}]")
            if found:
                return found
    return None


def _all_finite(obj) -> bool:
    """Whether every number in ``obj`` (dicts, lists, tuples, numbers) is finite: the test of
    :func:`first_non_finite` without the paths it builds on the way."""
    if isinstance(obj, float):
        return math.isfinite(obj)
    if isinstance(obj, dict):
        obj = obj.values()
    elif not isinstance(obj, (list, tuple)):
        return True
    for value in obj:
        if isinstance(value, float):
            if not math.isfinite(value):
                return False
        elif isinstance(value, (dict, list, tuple)) and not _all_finite(value):
            return False
    return True


SIGNIFICANT_DIGITS = 10
"""Significant digits of a number in a JSON output: relative precision 1e-10, whatever the
unit of the model (a coordinate of 1.234e-7 keeps its digits; fixed decimals would erase it)."""


def json_number(value, digits: int = SIGNIFICANT_DIGITS) -> float | None:
    """The JSON writer policy for one number: finite -> rounded to ``digits`` significant
    digits; NaN or infinite -> None (``null``)."""
    value = float(value)
    return float(f"{value:.{digits}g}") if math.isfinite(value) else None


def atomic_write_json(path: str | Path, obj, pretty: bool = False) -> None:
    """Serialize ``obj`` (compact, or ``pretty``: indented by two spaces) and write it
    atomically. NaN and infinity are refused (outputs carry ``null`` instead): a ``ValueError``
    names the file and the first offending field, and nothing is written.

    orjson formats the common case (str keys; str, int, float, bool, None, list, dict): a
    scene's ``poses3d.json`` in 0.1 ms with the check of its numbers, where the standard
    library's indented writer takes 0.7–2 ms. The standard library formats whatever orjson
    refuses."""
    if not _all_finite(obj):
        raise ValueError(f"{path}: {first_non_finite(obj)}: refusing to write a non-finite number")
    try:
        data = orjson.dumps(obj, option=orjson.OPT_INDENT_2 if pretty else 0)
    except TypeError:
        data = json.dumps(obj, indent=2 if pretty else None).encode()
    atomic_write_bytes(path, data)


#: The folders this process has swept of dead writers' temporaries (:func:`sweep_dead_temporaries`).
_SWEPT: set[str] = set()


def sweep_dead_temporaries(directory: str | Path) -> int:
    """Delete the temporary files in ``directory`` (``.NAME.mvm-tmp-PID-*``, regular files) whose
    writer, the process ``PID`` of this machine, is no longer alive: what a killed run left. Once
    per folder and process (a folder of thousands of frames is listed once, not at every write).
    No lock is needed: a live writer's temporary is never touched, nor one without a process
    number. The process numbers are this machine's: a folder that processes of several machines
    write at once (a network file system) must not be swept, and is not one mvm writes that way
    (each output is under one run's lock). Returns how many were deleted."""
    key = os.path.abspath(directory)
    if key in _SWEPT:
        return 0
    _SWEPT.add(key)
    removed = 0
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return 0
    for entry in entries:
        if not entry.name.startswith(".") or TEMPORARY_INFIX not in entry.name:
            continue
        pid = entry.name.split(TEMPORARY_INFIX, 1)[1].split("-", 1)[0]
        if not pid.isdigit() or not entry.is_file(follow_symlinks=False) or _alive(int(pid)):
            continue
        with contextlib.suppress(FileNotFoundError):
            os.unlink(entry.path)
            removed += 1
    return removed


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this machine (one that cannot be signalled counts as alive;
    a killed one its parent has not reaped yet, a zombie, does not: on Linux its state says so)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True
    try:
        stat_line = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return stat_line.rpartition(")")[2].split()[:1] != ["Z"]          # "PID (name) STATE ..."
