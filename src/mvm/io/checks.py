"""Checks shared by the readers: load a text or JSON file, and turn JSON/TOML values into
numbers, with every problem raised as one :class:`~mvm.errors.InputError` line."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from mvm.errors import InputError


def read_text(path: str | Path) -> str:
    """The UTF-8 text of ``path``; a missing, unreadable or non-UTF-8 file raises InputError."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except IsADirectoryError:
        raise InputError(path, None, "is a directory, expected a file") from None
    except UnicodeDecodeError as e:
        raise InputError(path, None, f"not UTF-8 text (byte {e.start})") from None
    except OSError as e:
        raise InputError(path, None, f"cannot read: {e.strerror}") from None


def load_json(path: str | Path):
    """Parse the JSON file ``path`` (any problem, including nesting too deep and integers too
    long to convert, raises InputError)."""
    text = read_text(path)
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(path, None, f"not valid JSON: {e}") from None
    except RecursionError:
        raise InputError(path, None, "not valid JSON: nested too deeply") from None
    except ValueError:  # an integer literal of more than 4300 digits
        raise InputError(path, None, "not valid JSON: a number has too many digits") from None


def load_toml(path: str | Path) -> dict:
    """Parse the TOML file ``path``; any problem raises InputError."""
    import tomllib

    text = read_text(path)
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
