"""A rig's output set (``poses3d.jsonl``, ``tracks/*.trc``, ``recap.json``) written as one unit.

The set is built in a temporary folder beside the output folder and swapped in whole
(:func:`mvm.io.files.atomic_replace_dir`): a reader sees the previous complete set or the new
complete set, never a new ``poses3d.jsonl`` beside an old ``recap.json`` nor ``.trc`` files left
from a longer earlier run. Writers of one output folder take turns (an exclusive lock on the
folder that holds it); the one holding the lock removes the temporary folders of killed runs.
"""
from __future__ import annotations

import logging
import shutil
from pathlib import Path
from typing import Callable

from mvm.errors import InputError
from mvm.io.files import LockTimeout, atomic_replace_dir, exclusive_lock

log = logging.getLogger(__name__)


def leftovers(path: Path) -> list[Path]:
    """Temporary folders of ``path``'s output set (``.NAME.*`` beside it). Only runs holding the
    lock create them, so while it is held every one found was left by a killed run."""
    return sorted(p for p in path.parent.glob(f".{path.name}.*") if p.is_dir() and not p.is_symlink())


def replace_output_set(build: Callable[[Path], None], path: str | Path, lock_timeout_s: float = 600.0) -> None:
    """Call ``build(folder)`` to write a complete output set into a fresh folder, then put it in
    place of ``path`` (a folder) in one rename. An exception in ``build`` leaves ``path`` as it
    was and no temporary folder; OS errors become :class:`InputError` naming ``path``."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(path, None, "exists and is not a folder: cannot write the rig's outputs there")
    try:
        with exclusive_lock(path.parent, lock_timeout_s):
            for stale in leftovers(path):
                log.info("removing %s, left by an interrupted run", stale)
                shutil.rmtree(stale, ignore_errors=True)
            atomic_replace_dir(build, path)
    except LockTimeout:
        raise InputError(path.parent, None, f"another mvm run has been writing here for more than "
                                            f"{lock_timeout_s:g} s") from None
    except OSError as e:
        raise InputError(path, None, f"cannot write the output folder: {e.strerror or e}") from None
