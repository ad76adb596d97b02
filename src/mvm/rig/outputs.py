"""A rig's output set (``poses3d.jsonl``, ``tracks/*.trc``, ``recap.json``) written as one unit.

The set is built in a temporary folder beside the output folder, named for the process that
builds it, and swapped in whole: a reader sees the previous complete set or the new complete
set, never a new ``poses3d.jsonl`` beside an old ``recap.json`` nor ``.trc`` files left from a
longer earlier run. Folders left by a killed run (its process gone) are removed by the next run.
"""
from __future__ import annotations

import logging
import os
import re
import shutil
import time
from pathlib import Path
from typing import Callable

from mvm.errors import InputError
from mvm.io.files import _fsync_dir

log = logging.getLogger(__name__)


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def leftovers(path: Path) -> list[Path]:
    """Temporary folders of ``path``'s output set left by runs whose process is gone."""
    pattern = re.compile(rf"^\.{re.escape(path.name)}\.(tmp|old)\.(\d+)(\.\d+)?$")
    found = []
    if path.parent.is_dir():
        for p in path.parent.iterdir():
            m = pattern.match(p.name)
            if m and not _alive(int(m.group(2))):
                found.append(p)
    return sorted(found)


def replace_output_set(build: Callable[[Path], None], path: str | Path) -> None:
    """Call ``build(folder)`` to write a complete output set into a fresh folder, then put it in
    place of ``path`` (a folder) in one rename. An exception in ``build`` leaves ``path`` as it
    was and no temporary folder. OS errors become :class:`InputError` naming ``path``."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.exists() and not path.is_dir():
            raise InputError(path, None, "exists and is not a folder: cannot write the rig's outputs there")
        for stale in leftovers(path):
            log.info("removing %s, left by an interrupted run", stale)
            shutil.rmtree(stale, ignore_errors=True)
        tag = f"{os.getpid()}.{time.time_ns()}"
        tmp = path.with_name(f".{path.name}.tmp.{tag}")
        tmp.mkdir()
    except OSError as e:
        raise InputError(path, None, f"cannot write the output folder: {e.strerror or e}") from None
    try:
        build(tmp)
        if path.exists():
            old = path.with_name(f".{path.name}.old.{tag}")
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        raise InputError(path, None, f"cannot write the output folder: {e.strerror or e}") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _fsync_dir(path.parent)
