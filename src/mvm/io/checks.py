"""Checks shared by the readers: open an input file the one guarded way, load a text, JSON or
TOML file, and turn JSON/TOML values into numbers, with every problem raised as one
:class:`~mvm.errors.InputError` line.

Every read of an input file goes through :func:`read_bytes`: the path must name a regular file
(a FIFO, a device such as ``/dev/zero`` or a folder is refused before anything is read, so a
read never blocks or runs away), its size is bounded (:data:`MAX_INPUT_BYTES`, set by the
``MVM_MAX_INPUT_MB`` environment variable), and with ``root`` the path, every symbolic link
resolved, must stay inside that folder (the scene directory).
"""
from __future__ import annotations

import contextlib
import gc
import json
import math
import os
import stat
from pathlib import Path

import numpy as np
import orjson

from mvm.errors import InputError


def _limit_from_env() -> int:
    try:
        megabytes = float(os.environ.get("MVM_MAX_INPUT_MB", "2048"))
    except ValueError:
        megabytes = 2048.0
    return int(megabytes * 2 ** 20) if math.isfinite(megabytes) and megabytes > 0 else 2048 * 2 ** 20


MAX_COORDINATE = 1e12
"""The largest coordinate magnitude (model units) a reader accepts, in a COLMAP model or a
``poses3d.json``: beyond it a squared distance or a projection could overflow, and no scene
measures that much in any unit."""

MAX_INPUT_BYTES = _limit_from_env()
"""The largest input file any reader accepts (bytes); ``MVM_MAX_INPUT_MB`` sets it (default 2048)."""


def _size_text(n: int) -> str:
    for unit, scale in (("GiB", 2 ** 30), ("MiB", 2 ** 20), ("KiB", 2 ** 10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n} bytes"


_KINDS = ((stat.S_ISDIR, "is a directory, expected a file"),
          (stat.S_ISFIFO, "is a FIFO (named pipe), expected a regular file"),
          (stat.S_ISCHR, "is a character device, expected a regular file"),
          (stat.S_ISBLK, "is a block device, expected a regular file"),
          (stat.S_ISSOCK, "is a socket, expected a regular file"))


def inside_root(path: str | Path, root: str | Path) -> Path:
    """``path`` when, with every symbolic link resolved, it lies inside ``root`` (resolved
    too); InputError otherwise (a link that leads out, a loop of links)."""
    path = Path(path)
    try:
        resolved = path.resolve()
        base = Path(root).resolve()
    except (OSError, RuntimeError) as e:               # a loop of symbolic links
        raise InputError(path, None, f"cannot resolve: {getattr(e, 'strerror', None) or e}") from None
    if resolved != base and base not in resolved.parents:
        raise InputError(path, None, f"leads outside {root} through a symbolic link")
    return path


def check_input_file(path: str | Path, root: str | Path | None = None, limit: int | None = None) -> Path:
    """``path`` when it names a regular file of at most ``limit`` bytes (inside ``root`` when
    given), for a reader that opens it itself (a link to it, a copy); InputError otherwise."""
    path = Path(path)
    if root is not None:
        inside_root(path, root)
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except OSError as e:
        raise InputError(path, None, f"cannot read: {e.strerror or e}") from None
    _check_kind(path, info, MAX_INPUT_BYTES if limit is None else limit)
    return path


def _check_kind(path: Path, info: os.stat_result, limit: int) -> None:
    for test, problem in _KINDS:
        if test(info.st_mode):
            raise InputError(path, None, problem)
    if not stat.S_ISREG(info.st_mode):
        raise InputError(path, None, "not a regular file")
    if info.st_size > limit:
        raise InputError(path, None, f"{_size_text(info.st_size)}, more than the "
                                     f"{_size_text(limit)} limit for an input file (MVM_MAX_INPUT_MB)")


def read_bytes(path: str | Path, root: str | Path | None = None, limit: int | None = None) -> bytes:
    """The content of the regular file ``path``, read the guarded way.

    Refused with :class:`InputError` naming the path: a missing file, a folder, a FIFO, a device
    or socket (checked on the opened descriptor, without blocking), a file over ``limit`` bytes
    (default :data:`MAX_INPUT_BYTES`), and with ``root`` a path that leads outside ``root``
    through a symbolic link.
    """
    path = Path(path)
    limit = MAX_INPUT_BYTES if limit is None else limit
    if root is not None:
        inside_root(path, root)
    try:
        fd = os.open(path, _READ_FLAGS)
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except IsADirectoryError:
        raise InputError(path, None, "is a directory, expected a file") from None
    except OSError as e:
        raise InputError(path, None, f"cannot read: {e.strerror or e}") from None
    return _read_open(path, fd, limit)


_READ_FLAGS = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)


def _read_open(path: Path, fd: int, limit: int) -> bytes:
    """Check the opened ``fd`` of ``path`` (a regular file of at most ``limit`` bytes), read it
    whole and close it."""
    try:
        _check_kind(path, os.fstat(fd), limit)
        chunks, total = [], 0
        while True:
            chunk = os.read(fd, min(1 << 24, limit + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > limit:
                raise InputError(path, None, f"grew past the {_size_text(limit)} limit for an input "
                                             "file while being read (MVM_MAX_INPUT_MB)")
        return b"".join(chunks)
    except OSError as e:
        raise InputError(path, None, f"cannot read: {e.strerror or e}") from None
    finally:
        os.close(fd)


def read_many(paths, root: str | Path | None = None, limit: int | None = None):
    """:func:`read_bytes` of each of ``paths`` in turn (a generator of ``bytes``): the same
    refusals, the same messages, at a fraction of the cost for many files of one folder.

    With ``root``, the folder of a run of paths is resolved and checked once and held open; each
    of its files is then opened relative to it without following a link (no path resolution):
    a file that is itself a symbolic link, or that cannot be opened that way, is read by
    :func:`read_bytes` (which resolves it, so a link out of ``root`` is refused as ever).
    """
    limit = MAX_INPUT_BYTES if limit is None else limit
    paths = [p if isinstance(p, Path) else Path(p) for p in paths]
    if root is None or not _NOFOLLOW or os.open not in os.supports_dir_fd:
        for path in paths:
            yield read_bytes(path, root, limit)
        return
    i = 0
    while i < len(paths):
        parent = paths[i].parent
        j = i
        while j < len(paths) and paths[j].parent == parent:
            j += 1
        folder = _open_checked_folder(parent, root)
        try:
            for path in paths[i:j]:
                fd = None
                if folder is not None and path.name not in ("", ".", ".."):
                    try:
                        fd = os.open(path.name, _READ_FLAGS | _NOFOLLOW, dir_fd=folder)
                    except OSError:                   # a link (ELOOP), missing…: the one-file way says why
                        fd = None
                yield read_bytes(path, root, limit) if fd is None else _read_open(path, fd, limit)
        finally:
            if folder is not None:
                os.close(folder)
        i = j


def _open_checked_folder(folder: Path, root: str | Path) -> int | None:
    """A descriptor of ``folder`` when, links resolved, it lies inside ``root`` (and is the folder
    the path names as it is opened); None otherwise (its files then take the one-file path)."""
    try:
        resolved = folder.resolve(strict=True)
        base = Path(root).resolve()
        if resolved != base and base not in resolved.parents:
            return None
        fd = os.open(resolved, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0))
    except (OSError, RuntimeError):
        return None
    try:
        opened, named = os.fstat(fd), os.stat(folder)
        if stat.S_ISDIR(opened.st_mode) and (opened.st_dev, opened.st_ino) == (named.st_dev, named.st_ino):
            return fd
    except OSError:
        pass
    os.close(fd)
    return None


def read_text(path: str | Path, root: str | Path | None = None) -> str:
    """The UTF-8 text of ``path`` (read by :func:`read_bytes`); a non-UTF-8 file raises InputError."""
    return decode_text(read_bytes(path, root), path)


def decode_text(data: bytes, path: str | Path) -> str:
    """``data`` read from ``path`` as UTF-8 text; anything else raises InputError."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise InputError(path, None, f"not UTF-8 text (byte {e.start})") from None


#: Every ASCII digit as "0": a run of 19 digits is then found by a plain substring search (a
#: regular expression costs as much as parsing the file).
_DIGITS_AS_ZERO = str.maketrans("123456789", "000000000")


def parse_json(text: str, path: str | Path):
    """Parse JSON ``text`` read from ``path``: invalid JSON, nesting too deep and integers too
    long to convert raise InputError; ``NaN`` and ``Infinity`` literals are kept as floats for
    the value checks (:func:`number`) to refuse where a number is expected.

    orjson parses standard JSON five times faster than the standard library (most of reading a
    rig's thousands of pose files). What it refuses (those literals, bad JSON), and any text with
    19 digits in a row (orjson turns integers beyond 64 bits into floats), is parsed by
    :func:`json.loads`, whose rules and messages stand."""
    if "0" * 19 not in text.translate(_DIGITS_AS_ZERO):
        try:
            return orjson.loads(text)
        except orjson.JSONDecodeError:
            pass
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(path, None, f"not valid JSON: {e}") from None
    except RecursionError:
        raise InputError(path, None, "not valid JSON: nested too deeply") from None
    except ValueError:  # an integer literal of more than 4300 digits
        raise InputError(path, None, "not valid JSON: a number has too many digits") from None


@contextlib.contextmanager
def collector_paused():
    """The cyclic garbage collector paused, for a reader that parses a large document into
    arrays and drops it: the parse makes a container for every object and list, none in a cycle,
    which the collector would otherwise go through again and again as they grow (a fifth of
    reading a long video's 2D poses); once dropped they are freed by their counts, with no
    collection."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def load_json(path: str | Path, root: str | Path | None = None):
    """Parse the JSON file ``path`` (read by :func:`read_bytes`; any problem raises InputError)."""
    return parse_json(read_text(path, root), path)


def load_json_object(path: str | Path, root: str | Path | None = None, what: str = "a JSON object") -> dict:
    """:func:`load_json` of a file whose top level must be an object."""
    data = load_json(path, root)
    if not isinstance(data, dict):
        raise InputError(path, None, f"expected {what}, got {_json_type(data)}")
    return data


def _json_type(value) -> str:
    return {dict: "an object", list: "a list", str: "a string", bool: "a boolean",
            type(None): "null"}.get(type(value), "a number")


def load_toml(path: str | Path, root: str | Path | None = None) -> dict:
    """Parse the TOML file ``path`` (read by :func:`read_bytes`); any problem raises InputError."""
    return parse_toml(read_text(path, root), path)


def parse_toml(text: str, path: str | Path | None) -> dict:
    """Parse TOML ``text`` read from ``path``; any problem raises InputError."""
    try:
        import tomllib
    except ModuleNotFoundError:                 # Python 3.10: the same parser, as a package
        import tomli as tomllib

    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise InputError(path, None, f"not valid TOML: {e}") from None
    except (RecursionError, ValueError) as e:  # nesting too deep, an out-of-range date…
        raise InputError(path, None, f"not valid TOML: {e or 'nested too deeply'}") from None


def number(value, path, field) -> float:
    """A finite JSON/TOML number (not a bool) as float."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(path, field, f"expected a number, got {type(value).__name__}")
    try:
        result = float(value)
    except OverflowError:
        raise InputError(path, field, "number too large") from None
    if not math.isfinite(result):
        raise InputError(path, field, f"not a finite number ({value})")
    return result


def integer(value, path, field) -> int:
    """A JSON integer (not a bool) that fits in 64 bits."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise InputError(path, field, f"expected an integer, got {_short(value)}")
    if not -(2 ** 63) <= value < 2 ** 63:
        raise InputError(path, field, "integer out of the 64-bit range")
    return value


def numbers(values, path, field, lengths: tuple[int, ...] | None = None, what: str = "") -> np.ndarray:
    """A flat list of finite numbers -> ``(n,)`` float array. ``lengths``: the allowed lengths
    (``what`` describes them in the message)."""
    if not isinstance(values, list):
        raise InputError(path, field, f"expected a list of numbers, got {type(values).__name__}")
    if lengths is not None and len(values) not in lengths:
        expected = what or " or ".join(str(n) for n in lengths) + " numbers"
        raise InputError(path, field, f"expected {expected}, got {len(values)}")
    if set(map(type, values)) <= {float, int}:                            # the common case, at once
        try:
            flat = np.array(values, dtype=float)
        except OverflowError:
            flat = None
        if flat is not None and np.isfinite(flat).all():
            return flat
    return np.array([number(v, path, f"{field}[{i}]") for i, v in enumerate(values)], dtype=float)


def matrix(values, shape: tuple[int, ...], path, field) -> np.ndarray:
    """A nested list of finite numbers of exactly ``shape`` -> float array."""
    def walk(value, depth, where):
        if depth == len(shape):
            return number(value, path, where)
        if not isinstance(value, list) or len(value) != shape[depth]:
            raise InputError(path, field, f"expected shape {shape}, got {_shape_of(values)}")
        return [walk(v, depth + 1, f"{where}[{i}]") for i, v in enumerate(value)]
    return np.array(walk(values, 0, field), dtype=float).reshape(shape)


def _shape_of(value) -> str:
    if not isinstance(value, list):
        return type(value).__name__
    dims = []
    while isinstance(value, list):
        dims.append(len(value))
        if not value:
            break
        value = value[0]
    return "(" + ", ".join(str(d) for d in dims) + ("," if len(dims) == 1 else "") + ")"


def _short(value, limit: int = 40) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"
