"""Outputs that know their inputs: a record beside every stage's output of what it was made from.

Every stage (frames, SfM, detection, reconstruction, a rig's reconstruction, the batch export)
writes beside its output ``OUTPUT`` a small JSON file ``<stem>.inputs.json``
(:func:`record_path`; ``poses2d.json`` -> ``poses2d.inputs.json``) holding

- ``inputs``: a content hash of each input (:func:`fingerprint`: BLAKE2b of a file's bytes; of
  a folder, of the sorted list of its files' names and hashes), or of a value the stage read
  (the names of the frames SfM registered);
- ``settings``: the effective settings that shaped the output (JSON values).

A rerun compares them with what it would use now (:func:`why_redo`): equal, the output is kept;
otherwise the reason is one phrase naming what changed (``poses2d.json changed since the
reconstruction``, ``setting blur_ratio changed since the frame extraction (0.35 -> 0)``).
The record is removed before its output is replaced and written after it, so an output
without a record (an interrupted run, an output made elsewhere) is never taken as up to date.

Hashing reads every input's bytes (about 1 GB/s): a rerun with nothing changed costs the
hashing of the inputs, milliseconds for a scene's JSON and frames, a second per GB of video.
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import logging
import os
import stat
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import orjson

from mvm.errors import InputError
from mvm.io.checks import check_input_file, read_bytes
from mvm.io.files import atomic_write_json, check_file_target, output_error
from mvm.io.outputs import output_lock

log = logging.getLogger(__name__)

RECORD_FORMAT = "mvm.inputs/1"
#: The largest record read back (one holds a few hashes and the settings). [bytes]
RECORD_MAX_BYTES = 2**20
#: The deepest nesting of lists and objects in a record read back (one nests four or five).
RECORD_MAX_DEPTH = 32
#: Suffix of a record beside its output: ``poses2d.json`` -> ``poses2d.inputs.json``.
RECORD_SUFFIX = ".inputs.json"
#: The fingerprint of an input that is not there.
MISSING = "missing"

_CHUNK = 1 << 20
#: Hashes already computed by this process, by the file's identity and change times: a file is
#: read once per process however many checks name it (any write changes its ctime). A file
#: changed in the last :data:`_RACY_NS` is always read (timestamps are coarser than writes).
_SEEN: dict[tuple, str] = {}
_RACY_NS = 3_000_000_000
_READ_FLAGS = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)


def record_path(output: str | Path) -> Path:
    """The record of ``output`` (a file or a folder): ``<stem>.inputs.json`` beside it."""
    output = Path(output)
    stem = output.name[: -len(output.suffix)] if output.suffix and not output.is_dir() else output.name
    return output.with_name(stem + RECORD_SUFFIX)


def _hash_file(path: Path) -> str:
    """BLAKE2b of the bytes of the regular file ``path``, read in chunks; a FIFO, a device or a
    socket is refused (never read) with the guarded reader's line
    (:func:`mvm.io.checks.check_input_file`; any size: a video may be large)."""
    check_input_file(path, limit=sys.maxsize)
    try:
        fd = os.open(path, _READ_FLAGS)
    except OSError as e:
        raise InputError(path, None, f"cannot read: {e.strerror or e}") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise InputError(path, None, "not a regular file")
        key = (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns, info.st_ctime_ns)
        if key in _SEEN:
            return _SEEN[key]
        h = hashlib.blake2b(digest_size=20)
        while chunk := os.read(fd, _CHUNK):
            h.update(chunk)
        digest = h.hexdigest()
        if time.time_ns() - max(info.st_mtime_ns, info.st_ctime_ns) > _RACY_NS:
            if len(_SEEN) > 100_000:
                _SEEN.clear()
            _SEEN[key] = digest
        return digest
    except OSError as e:
        raise InputError(path, None, f"cannot read: {e.strerror or e}") from None
    finally:
        os.close(fd)


def clear_hash_cache() -> None:
    """Forget the hashes this process computed: the next check reads every input again, as a
    new process does."""
    _SEEN.clear()


def fingerprint(path: str | Path) -> str:
    """The content hash of ``path``: of a file, its bytes; of a folder, the sorted list of
    ``(relative name, hash)`` of the files under it (names starting with ``.``, such as lock
    and marker files, left out); :data:`MISSING` when there is nothing at ``path``."""
    path = Path(path)
    if not path.exists():
        return MISSING
    if not path.is_dir():
        return _hash_file(path)
    h = hashlib.blake2b(digest_size=20)
    for file in _files(path):
        h.update(file.relative_to(path).as_posix().encode() + b"\0" + _hash_file(file).encode() + b"\0")
    return "dir:" + h.hexdigest()


def _files(folder: Path) -> list[Path]:
    found = []
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        found += [Path(root) / f for f in files if not f.startswith(".")]
    return sorted(found, key=lambda p: p.relative_to(folder).as_posix())


def _plain(value):
    """``value`` as JSON values: dataclasses as dicts, paths and other objects as strings."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _plain(dataclasses.asdict(value))
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        return value if value == value and abs(value) != float("inf") else str(value)
    return str(value)


def value_fingerprint(value) -> str:
    """The hash of a value (JSON values, dataclasses; keys sorted): for an input read as a value."""
    data = orjson.dumps(_plain(value), option=orjson.OPT_SORT_KEYS)
    return "value:" + hashlib.blake2b(data, digest_size=20).hexdigest()


def fingerprints(inputs: Mapping[str, object]) -> dict[str, str]:
    """``{name: fingerprint}`` of ``inputs``: a :class:`~pathlib.Path` is hashed
    (:func:`fingerprint`), anything else is a value (:func:`value_fingerprint`)."""
    return {name: fingerprint(v) if isinstance(v, Path) else value_fingerprint(v) for name, v in inputs.items()}


def read_record(output: str | Path) -> dict | None:
    """The record of ``output``, or None when there is none or it cannot be read (an output
    without a usable record is never up to date, and a rerun says why)."""
    return _load_record(output)[0]


def _load_record(output: str | Path) -> tuple[dict | None, str | None]:
    """``(record, None)``, ``(None, None)`` when nothing is there, or ``(None, problem)``.

    A record is written in place as a small regular file: a link there (to another output's
    record, say), a FIFO, a device, a folder, a file over :data:`RECORD_MAX_BYTES`, text that
    is not JSON, JSON nested deeper than :data:`RECORD_MAX_DEPTH` or without the record's
    fields is no record of this output."""
    path = record_path(output)
    if not os.path.lexists(path):
        return None, None
    if path.is_symlink():
        return None, f"{path.name} is a symbolic link, not a record"
    try:
        data = orjson.loads(read_bytes(path, limit=RECORD_MAX_BYTES))   # a FIFO or a huge file: no record
    except InputError as e:
        return None, f"{path.name}: {e.problem}"
    except orjson.JSONDecodeError:
        return None, f"{path.name} is not JSON"
    if _depth(data) > RECORD_MAX_DEPTH:
        return None, f"{path.name} is nested deeper than {RECORD_MAX_DEPTH} levels"
    if not isinstance(data, dict) or data.get("format") != RECORD_FORMAT or not isinstance(data.get("inputs"), dict):
        return None, f"{path.name} is not an {RECORD_FORMAT} record"
    return data, None


def _depth(value, limit: int = RECORD_MAX_DEPTH) -> int:
    """How deep ``value`` nests lists and objects (a number: 0; ``[[1]]``: 2), counted level by
    level without recursion, up to ``limit + 1``."""
    depth, level = 0, [value]
    while depth <= limit:
        level = [v for item in level if isinstance(item, (dict, list))
                 for v in (item.values() if isinstance(item, dict) else item)] if any(
                     isinstance(item, (dict, list)) for item in level) else None
        if level is None:
            return depth
        depth += 1
    return depth


def forget(output: str | Path) -> None:
    """Remove the record of ``output``: call it before replacing the output. Whatever lies at
    the record's name (mvm's own) is removed, a link itself and not what it points to; a
    device or a folder there is refused in one line (:func:`mvm.io.files.check_file_target`),
    and so is a record that cannot be removed (:class:`~mvm.io.files.OutputError`)."""
    path = record_path(output)
    if not path.is_symlink() and not stat.S_ISFIFO(_mode(path)):
        check_file_target(path)
    try:
        path.unlink(missing_ok=True)
    except OSError as e:
        raise output_error(path, e) from None


def _mode(path: Path) -> int:
    try:
        return os.lstat(path).st_mode
    except OSError:
        return 0


def write_record(output: str | Path, stage: str, inputs: Mapping[str, object], settings=None,
                 hashed: Mapping[str, str] | None = None, made: list[Path] | None = None) -> dict:
    """Write the record of ``output``, made by ``stage`` (its name in :func:`why_redo`'s
    reasons, e.g. "the reconstruction") from ``inputs`` (:func:`fingerprints`; ``hashed``: those
    already computed) with ``settings`` (a dataclass or JSON values). ``made``: the files the
    output consists of besides ``output`` itself (a frame extraction's images), under the
    record's folder; one of them gone makes the output stale. Returns the record."""
    record = {"format": RECORD_FORMAT, "stage": stage,
              "inputs": dict(hashed) if hashed is not None else fingerprints(inputs),
              "settings": _plain(settings) if settings is not None else {}}
    path = record_path(output)
    if made is not None:
        record["made"] = [Path(m).relative_to(path.parent).as_posix() for m in made]
    if not stat.S_ISREG(_mode(path)):
        forget(output)                             # a link or a FIFO there: removed; a device, a folder: refused
    atomic_write_json(path, record, pretty=True)
    return record


def _gone(output: Path, record: dict, what: str) -> str | None:
    """Which of the files the record says the output is made of is no longer a regular file."""
    made = record.get("made", [])
    if not isinstance(made, list):
        return f"{record_path(output).name}: made: not a list"
    folder = record_path(output).parent
    for name in made:
        if not isinstance(name, str) or name.startswith("/") or ".." in name.split("/"):
            return f"{record_path(output).name}: made: {str(name)[:40]!r} is not a file of the output"
        if not stat.S_ISREG(_mode(folder / name)):
            return f"{name} is gone since {what}"
    return None


def _flat(settings, prefix: str = "") -> dict:
    if not isinstance(settings, dict):
        return {prefix or "settings": settings}
    out = {}
    for k, v in settings.items():
        key = f"{prefix}.{k}" if prefix else k
        out.update(_flat(v, key) if isinstance(v, dict) else {key: v})
    return out


def _short(value) -> str:
    text = orjson.dumps(value).decode() if not isinstance(value, str) else value
    return text if len(text) <= 40 else text[:37] + "…"


def compare(record: dict, inputs: Mapping[str, str], settings=None, stage: str | None = None) -> str | None:
    """Why ``record`` does not describe an output made now from ``inputs`` (``{name:
    fingerprint}``) with ``settings`` (None: settings not compared): one phrase, or None when
    it does."""
    what = stage or record.get("stage") or "the output was made"
    before = record.get("inputs", {})
    for name, now in inputs.items():
        if name not in before:
            return f"{name} is new since {what}"
        if before[name] != now:
            if now == MISSING:
                return f"{name} is gone since {what}"
            return f"{name} changed since {what}"
    for name in before:
        if name not in inputs:
            return f"{name} is no longer an input since {what}"
    if settings is not None:
        old, new = _flat(record.get("settings", {})), _flat(_plain(settings))
        for key in sorted(set(old) | set(new)):
            if old.get(key, MISSING) != new.get(key, MISSING):
                return (f"setting {key} changed since {what} "
                        f"({_short(old.get(key, '(unset)'))} -> {_short(new.get(key, '(unset)'))})")
    return None


def why_redo(output: str | Path, inputs: Mapping[str, object], settings=None, stage: str = "the output was made",
             exists: bool | None = None, hashed: Mapping[str, str] | None = None) -> str | None:
    """Why ``output`` should be made again from ``inputs`` (:func:`fingerprints`; ``hashed``:
    those already computed, not hashed again) and ``settings``: one phrase (``no output yet``,
    ``poses2d.json changed since the reconstruction``, ...), or None when its record says it was
    made from exactly these."""
    output = Path(output)
    if not (output.exists() if exists is None else exists):
        return "no output yet"
    mode = _mode(output)
    if mode and not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        return f"{output.name} is not a regular file"          # a link, FIFO or device is no output of mvm
    record, problem = _load_record(output)
    if problem is not None:
        return f"its record is unusable ({problem})"
    if record is None:
        return (f"{output.name} has no record of its inputs (made elsewhere, by an earlier version or an "
                "interrupted run)")
    return (compare(record, fingerprints(inputs) if hashed is None else hashed, settings, stage)
            or _gone(output, record, stage))


def stale_reason(output: str | Path, inputs: Mapping[str, object]) -> str | None:
    """For a command that reads ``output``: why it no longer matches those of its ``inputs``
    that its record names (settings are not compared) or a file it lists is gone, or None when
    it does or when it has no record (an output made elsewhere is taken as it is). A record that
    is there but unusable (not a small regular JSON file of the record's form) makes it stale."""
    record, problem = _load_record(output)
    if problem is not None:
        return f"its record is unusable ({problem})"
    if record is None:
        return None
    known = {name: value for name, value in inputs.items() if name in record["inputs"]}
    return (compare({**record, "inputs": {k: record["inputs"][k] for k in known}}, fingerprints(known))
            or _gone(Path(output), record, record.get("stage") or "the output was made"))


def check_fresh(output: str | Path, inputs: Mapping[str, object], command: str) -> None:
    """Refuse to read a stale ``output``: one :class:`InputError` line (exit 2) saying what
    changed and naming ``command``, the command that brings it up to date."""
    reason = stale_reason(output, inputs)
    if reason is not None:
        raise InputError(output, None, f"out of date: {reason}: run `{command}` first")


def produce(output: str | Path, stage: str, inputs: Mapping[str, object], settings, make: Callable,
            keep: Callable | None, *, force: bool = False, exists: bool | None = None, lock: str | Path | None = None,
            lock_timeout_s: float = 600.0, hashed: Mapping[str, str] | None = None,
            made: Callable | None = None) -> tuple[object, str | None]:
    """Make ``output`` of ``stage`` (its name in the reasons, "the reconstruction") when it is
    not up to date, the one way every stage does it: fingerprint the ``inputs`` (``hashed``:
    those already taken), ask :func:`why_redo` (``exists``: whether the output is all there,
    when its file alone does not say), and, when it must be made (or ``force``), under the
    lock of the output ``lock`` (a file, or a folder written whole;
    :func:`mvm.io.outputs.output_lock`): remove the record, ``make(why, hashed)`` (which writes
    the outputs atomically and returns the stage's result; it may update ``hashed`` for an
    input it rewrote, a camera model it scaled), then write the record (``made(result)``: the
    files the output consists of besides ``output``, :func:`write_record`).

    Returns ``(result, why)``: ``why`` None when the output was up to date and ``keep()`` is
    the result. A lock held past ``lock_timeout_s`` by another run is one error line.
    """
    output = Path(output)
    hashed = dict(fingerprints(inputs) if hashed is None else hashed)
    why = "forced" if force else why_redo(output, inputs, settings, stage, exists=exists, hashed=hashed)
    if why is None:
        log.info("%s is up to date (%s: made from these inputs with these settings)", output, stage)
        return (keep() if keep is not None else None), None
    with output_lock(lock, lock_timeout_s) if lock is not None else contextlib.nullcontext():
        forget(output)
        result = make(why, hashed)
        write_record(output, stage, inputs, settings, hashed, made=made(result) if made is not None else None)
    return result, why
