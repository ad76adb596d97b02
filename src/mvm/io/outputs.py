"""Output folders: mvm writes only where it owns.

Three rules keep a command from destroying what it did not make:

* **Location** (:func:`check_output_location`): an output that is an input of the run,
  contains one, or lies inside an input folder is refused before any work, in one line.
* **Ownership**: a folder mvm writes as one set (:func:`atomic_replace_dir`) carries the marker
  file :data:`OUTPUT_MARKER`, which lists the names written. An existing folder is replaced
  only when it is empty, or carries the marker and holds nothing else; a user's folder, or a
  file a user added to an output, is refused (:func:`check_replaceable`). A temporary folder is
  named ``.NAME.mvm-tmp-RANDOM`` *and* carries :data:`TEMPORARY_MARKER`; the leftovers of a
  killed run are removed only when both hold (:func:`remove_leftovers`), never a user's
  ``.NAME.backup`` beside the output.
* **What lies there** (:func:`check_may_write`, the one decision every writer follows): a FIFO,
  a device, a socket or a link where an output goes is refused; a file a command names inside a
  folder it is given (``D/clips.csv``, ``SCENE/poses2d.json``) is replaced only when mvm wrote it
  (the folder's marker lists it, :func:`writing_into`, or its record lies beside it).
* **One writer** (:func:`output_lock`): a run holds an ``flock`` on ``.NAME.lock`` beside the
  output while it writes (opened without following a link). A second run into the same output
  waits a bounded time, then is refused in one line; the lock dies with its process, so a killed
  run never blocks the next.
"""
from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import stat
import tempfile
import time
from collections.abc import Callable, Iterable
from pathlib import Path

from mvm.io.files import (
    TEMPORARY_INFIX,
    OutputError,
    atomic_write_text,
    check_file_target,
    fsync_dir,
    make_dir,
    new_dir_mode,
    output_error,
)

try:
    import fcntl
except ImportError:                                    # not POSIX: no advisory locks
    fcntl = None

#: File inside every folder that mvm wrote as one output set: replacing that folder is allowed.
OUTPUT_MARKER = ".mvm-output"
#: File inside every temporary folder mvm makes: only such folders are removed as leftovers.
TEMPORARY_MARKER = ".mvm-temporary"
#: How a lock file is opened: created if absent, never through a link, never blocking on a FIFO.
_LOCK_FLAGS = (os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOFOLLOW", 0)
               | getattr(os, "O_NONBLOCK", 0))
#: The lock of a folder's marker while a run lists its names there (:func:`writing_into`).
_MARKER_LOCK = f".{OUTPUT_MARKER}.lock"
#: Seconds a run waits for another run writing the same output before refusing.
LOCK_WAIT_S = 10.0


def _resolved(path: str | Path) -> Path:
    return Path(os.path.abspath(Path(path).expanduser())).resolve()


def _contains(folder: Path, path: Path) -> bool:
    return folder == path or folder in path.parents


def check_output_location(output: str | Path, inputs: Iterable[str | Path], replaced: bool = True) -> Path:
    """Refuse ``output`` when it is one of ``inputs``, contains one, or lies inside an input
    folder (symbolic links resolved); with ``replaced`` (a folder written as one set, which
    replaces what is there) also refuse an existing non-empty folder that mvm did not make
    (:func:`check_replaceable`); without, refuse a FIFO, a device, a socket or a link to a file
    there (:func:`check_may_write`). Each refusal is one :class:`OutputError` line naming
    ``output``. Call it before any work. Returns ``output`` as a :class:`Path`."""
    output = Path(output)
    target = _resolved(output)
    sources = [(given, _resolved(given)) for given in inputs]
    for given, source in sources:
        if target == source:
            raise OutputError(output, None, f"is an input of this run ({given}): choose another output")
    for given, source in sources:
        if _contains(target, source):
            raise OutputError(output, None, f"contains the input {given}: writing there would replace it; "
                                            "choose another output")
    for given, source in sources:
        if source.is_dir() and _contains(source, target):
            raise OutputError(output, None, f"lies inside the input folder {given}: choose another output")
    if replaced:
        check_replaceable(output)
    else:
        check_may_write(output)                        # -o /dev/null, a FIFO, a link to a file: refused now
    return output


def check_replaceable(path: str | Path) -> None:
    """Refuse, in one :class:`OutputError` line, to replace ``path`` when it is not a folder, a
    non-empty folder without :data:`OUTPUT_MARKER` (a folder mvm did not make), or an output
    folder holding a name its marker does not list (something a user put there)."""
    path = Path(path)
    if not path.exists():
        return
    if not path.is_dir():
        raise OutputError(path, None, "cannot write: exists and is not a folder")
    try:
        names = sorted(os.listdir(path))
    except OSError as e:
        raise output_error(path, e) from None
    if not names:
        return
    written = _marked_names(path)
    if written is None:
        raise OutputError(path, None, f"is a folder mvm did not make (no {OUTPUT_MARKER} inside) and not empty: "
                                      "it would be replaced; choose a new or empty folder")
    other = [n for n in names if n not in written and n not in (OUTPUT_MARKER, TEMPORARY_MARKER, _MARKER_LOCK)
             and not _own_temporary(n, written)]
    if other:
        raise OutputError(path, None, f"holds {other[0]!r}, which mvm did not write there: it would be "
                                      "replaced; move it or choose a new or empty folder")


def _own_temporary(name: str, written: set[str]) -> bool:
    """Whether ``name`` is the lock or a temporary of an entry the marker lists (what a killed
    writer of an entry added to the set, :func:`add_to_output_set`, may leave)."""
    if not name.startswith("."):
        return False
    return any(name == f".{w}.lock" or name.startswith(f".{w}{TEMPORARY_INFIX}") for w in written)


def add_to_output_set(folder: str | Path, name: str, write: Callable[[Path], None],
                      lock_timeout_s: float = LOCK_WAIT_S) -> Path:
    """Write ``folder/name`` with ``write(path)`` (an atomic writer: a file by
    :func:`mvm.io.files.atomic_write_bytes`, a folder by :func:`atomic_replace_dir`) into the
    output set ``folder``, holding the set's lock, and list ``name`` in the set's marker first: the
    next run that replaces the set replaces it too (a report drawn from the set goes with it). A
    ``folder`` without the marker is written into as any folder. Returns the path written."""
    folder = Path(folder)
    with output_lock(folder, lock_timeout_s):
        written = _marked_names(folder)
        if written is not None:
            _list_names(folder, written, [name])
        write(folder / name)
    return folder / name


@contextlib.contextmanager
def writing_into(folder: str | Path, names: Iterable[str], lock_timeout_s: float = LOCK_WAIT_S):
    """Decide whether a command may write the entries ``names`` (names mvm chooses: a scene's
    ``poses2d.json``, a report folder's ``clips.csv``) into ``folder`` (one a user names), and
    hold the folder while it does. Under the folder's lock (``.mvm-output`` 's lock inside it)
    each name is checked (:func:`check_may_write`): nothing there, or an entry that mvm made
    (listed in the folder's :data:`OUTPUT_MARKER`, or carrying the record of its inputs that
    an mvm stage wrote beside it); a user's file of that name, or a link, FIFO, device or socket
    in its place, is refused in one :class:`OutputError` line before anything is written. The
    names are then listed in the marker (created when absent) so that the next run knows them
    as its own, and the block writes them (the atomic writer removes the temporaries that a
    killed writer left, :func:`mvm.io.files.sweep_dead_temporaries`). Yields ``folder`` as a :class:`Path`."""
    folder, names = Path(folder), list(names)
    created = not os.path.lexists(folder)
    make_dir(folder)
    try:
        with output_lock(folder / OUTPUT_MARKER, lock_timeout_s):
            written = check_names(folder, names)
            _list_names(folder, written, names)
            try:
                yield folder
            except BaseException:                     # a failed run lists only what it left
                _unlist_missing(folder, written, names)
                raise
    finally:
        if created:
            _remove_if_bare(folder)


def _list_names(folder: Path, written: set[str] | None, names: list[str]) -> None:
    """List ``names`` in ``folder``'s marker (which lists ``written``; None: no marker yet)."""
    if written is None or not set(names) <= written:
        atomic_write_text(folder / OUTPUT_MARKER, json.dumps(sorted((written or set()) | set(names))))


def _unlist_missing(folder: Path, written: set[str] | None, names: list[str]) -> None:
    """Put ``folder``'s marker back to ``written`` and the ``names`` that are there now."""
    made = {n for n in names if os.path.lexists(folder / n)}
    with contextlib.suppress(OSError, OutputError):
        if written is None and not made:
            (folder / OUTPUT_MARKER).unlink(missing_ok=True)
        else:
            atomic_write_text(folder / OUTPUT_MARKER, json.dumps(sorted((written or set()) | made)))


def _remove_if_bare(folder: Path) -> None:
    """Remove ``folder`` (which a failed or refused run created) when it holds its marker at most."""
    with contextlib.suppress(OSError):
        if set(os.listdir(folder)) <= {OUTPUT_MARKER}:
            (folder / OUTPUT_MARKER).unlink(missing_ok=True)
            folder.rmdir()


def check_names(folder: str | Path, names: Iterable[str]) -> set[str] | None:
    """Refuse (:func:`check_may_write`) any of ``names`` in ``folder`` that mvm may not write
    there; returns the names the folder's marker lists (None: no marker). For a check before
    any work; :func:`writing_into` checks again under the lock when it writes."""
    folder = Path(folder)
    written = _marked_names(folder)
    for name in names:
        check_may_write(folder / name, owned=written or set())
    return written


def check_may_write(path: str | Path, owned: Iterable[str] | None = None) -> None:
    """Whether mvm may put its output at ``path``: the one decision every writer follows.

    Refused in one :class:`OutputError` line (exit 2), before any write: a symbolic link, a
    FIFO, a device or a socket at ``path`` (:func:`mvm.io.files.check_file_target`; a folder,
    or a link to one, is let through for an output that is a folder: where it may lie is
    :func:`check_output_location`'s to say). With ``owned`` (the names of ``path``'s folder
    that mvm wrote, :data:`OUTPUT_MARKER`'s list; None when the user named ``path`` itself, so it
    is theirs to replace): an existing entry not in ``owned`` and without an mvm record of its
    inputs beside it (:func:`mvm.io.provenance.record_path`) is a user's and never replaced."""
    path = Path(path)
    try:
        info = os.lstat(path)
    except FileNotFoundError:
        return
    except OSError as e:
        raise output_error(path, e) from None
    if not (stat.S_ISDIR(info.st_mode) or stat.S_ISLNK(info.st_mode) and path.is_dir()):
        check_file_target(path)                        # a folder, or a link to one, is an output folder's place
    if owned is None or path.name in set(owned) or _has_record(path):
        return
    raise OutputError(path, None, "exists and mvm did not write it (not listed in the folder's "
                                  f"{OUTPUT_MARKER}): it would be replaced; move it or choose another output")


def _has_record(path: Path) -> bool:
    """Whether an mvm stage wrote ``path``: the record of its inputs lies beside it."""
    from mvm.io.provenance import record_path

    record = record_path(path)
    return record != path and record.is_file() and not record.is_symlink()


def is_mvm_output(path: str | Path) -> bool:
    """Whether ``path`` is a folder that mvm wrote as one output set (it carries the marker)."""
    return _marked_names(Path(path)) is not None


def _marked_names(path: Path) -> set[str] | None:
    """The names mvm wrote at the top of output folder ``path`` (listed in its marker), or None
    when ``path`` carries no marker (a regular file, read as JSON: a list of names)."""
    marker = path / OUTPUT_MARKER
    if marker.is_symlink() or not marker.is_file():
        return None
    try:
        names = json.loads(marker.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        return None
    return set(names)


def _mark_output(folder: Path) -> None:
    """Write :data:`OUTPUT_MARKER` into ``folder``: the names of what it holds."""
    names = sorted(n for n in os.listdir(folder) if n not in (OUTPUT_MARKER, TEMPORARY_MARKER))
    (folder / OUTPUT_MARKER).write_text(json.dumps(names), encoding="utf-8")


def make_temporary_dir(path: str | Path) -> Path:
    """A fresh folder ``.NAME.mvm-tmp-RANDOM`` beside ``path`` carrying :data:`TEMPORARY_MARKER`,
    with the mode of a new folder under the process umask (``0755`` under ``022``), not
    :func:`tempfile.mkdtemp`'s private ``0700``: it becomes the output folder."""
    path = Path(path)
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}{TEMPORARY_INFIX}", dir=path.parent))
    except OSError as e:
        raise output_error(path, e) from None
    try:
        os.chmod(tmp, new_dir_mode())
        (tmp / TEMPORARY_MARKER).touch()
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        raise output_error(path, e) from None
    return tmp


def leftovers(path: str | Path) -> list[Path]:
    """The temporary folders of ``path`` that a killed run left: named ``.NAME.mvm-tmp-*``
    beside it, real folders (not links), each carrying :data:`TEMPORARY_MARKER` (a regular file).
    Only a run holding :func:`output_lock` on ``path`` makes them, so under the lock every one
    found is a leftover."""
    path = Path(path)
    found = []
    for p in path.parent.glob(f".{path.name}{TEMPORARY_INFIX}*"):
        marker = p / TEMPORARY_MARKER
        if p.is_dir() and not p.is_symlink() and marker.is_file() and not marker.is_symlink():
            found.append(p)
    return sorted(found)


def remove_leftovers(path: str | Path) -> int:
    """Delete :func:`leftovers` of ``path``; returns how many. Call it holding :func:`output_lock`."""
    stale = leftovers(path)
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    return len(stale)


def lock_path(path: str | Path) -> Path:
    """The lock file of output ``path``: ``.NAME.lock`` beside it."""
    path = Path(path)
    return path.with_name(f".{path.name}.lock")


@contextlib.contextmanager
def output_lock(path: str | Path, timeout_s: float = LOCK_WAIT_S, poll_s: float = 0.05):
    """Hold the one writer's lock of output ``path`` (``flock`` on :func:`lock_path`, made in the
    folder that holds ``path``). Waits up to ``timeout_s`` for another holder, then raises one
    :class:`OutputError` line: ``another mvm run is writing PATH``. The lock file is removed on
    release; the lock itself is released by the kernel if the process dies. Without ``fcntl``
    (not POSIX) it does not lock."""
    path = Path(path)
    make_dir(path.parent)
    if fcntl is None:
        yield
        return
    lock = lock_path(path)
    deadline = time.monotonic() + timeout_s
    while True:
        check_file_target(lock)                        # a planted link, FIFO or device: refused
        try:
            fd = os.open(lock, _LOCK_FLAGS, 0o644)
        except OSError as e:
            if e.errno == errno.ELOOP:                 # a link planted since the check
                raise OutputError(lock, None, "refusing to write: is a symbolic link, not a regular file; "
                                              "choose another output") from None
            raise output_error(lock, e) from None
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            raise OutputError(lock, None, "refusing to write: not a regular file; choose another output")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            if time.monotonic() >= deadline:
                raise OutputError(path, None, f"another mvm run is writing {path} (waited {timeout_s:g} s): "
                                              "try again when it has finished") from None
            time.sleep(poll_s)
            continue
        # the holder before us may have removed the file it locked: ours must still be the one named
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(lock))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock)                            # while still held: the next holder checks the name
        os.close(fd)


def atomic_replace_dir(build: Callable[[Path], None], path: str | Path, replace_unmarked: bool = False,
                       lock_timeout_s: float = LOCK_WAIT_S) -> None:
    """Call ``build(tmp_dir)`` to fill a fresh folder, then put it in place of ``path``.

    An existing ``path`` is replaced only once the new content is complete, so the folder is
    one output set: a reader sees the previous set or the new one, never a mix, and nothing of
    an earlier, larger set survives. The new folder carries :data:`OUTPUT_MARKER`. An existing
    non-empty ``path`` without it is refused (:func:`check_replaceable`) unless
    ``replace_unmarked`` (a folder that is the scene's own by design, such as its ``sparse/``
    model). The run holds :func:`output_lock` on ``path`` (waiting at most ``lock_timeout_s``)
    and first removes the :func:`leftovers` of killed runs. An OS error raises
    :class:`OutputError` naming ``path``.
    """
    path = Path(path)
    make_dir(path.parent)
    with output_lock(path, lock_timeout_s):
        if path.exists() and not path.is_dir():
            raise OutputError(path, None, "cannot write: exists and is not a folder")
        if not replace_unmarked:
            check_replaceable(path)
        remove_leftovers(path)
        tmp = make_temporary_dir(path)
        try:
            build(tmp)
            _mark_output(tmp)
            if path.exists():
                _swap(tmp, path)
            else:
                os.replace(tmp, path)
            (path / TEMPORARY_MARKER).unlink()            # a run killed before this left a complete set
        except OSError as e:
            shutil.rmtree(tmp, ignore_errors=True)
            raise output_error(path, e) from None
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        fsync_dir(path.parent)


def _swap(new: Path, path: Path) -> None:
    """Put folder ``new`` in place of folder ``path``: the previous set first moves inside a
    marked temporary folder (removed at once, or as a leftover by the next run), and comes back
    if the second rename fails."""
    trash = make_temporary_dir(path)
    previous = trash / "previous"
    os.replace(path, previous)
    try:
        os.replace(new, path)
    except OSError:
        with contextlib.suppress(OSError):
            os.replace(previous, path)
        shutil.rmtree(trash, ignore_errors=True)
        raise
    shutil.rmtree(trash, ignore_errors=True)
