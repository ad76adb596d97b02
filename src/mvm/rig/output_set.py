"""A rig's output set (``poses3d.jsonl``, ``tracks/*.trc``, ``recap.json``) written as one unit.

The set is built in a temporary folder beside the output folder and swapped in whole
(:func:`mvm.io.outputs.atomic_replace_dir`): a reader sees the previous complete set or the new
complete set, never a new ``poses3d.jsonl`` beside an old ``recap.json`` nor ``.trc`` files left
from a longer earlier run. Writers of one output folder take turns (its lock); the one holding
the lock removes the marked temporary folders of killed runs. The output folder is checked
before any work: never the rig's calibration or pose folders, nor a user's folder.
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from mvm.io.layout import RigLayout
from mvm.io.outputs import LOCK_WAIT_S, atomic_replace_dir, check_output_location, is_mvm_output
from mvm.rig.rigdir import find_calibration, pose_sources


def rig_inputs(rig_dir: str | Path, calib: str | Path | None = None) -> list[Path]:
    """What :func:`mvm.rig.rigdir.read_rig` reads from ``rig_dir``: the calibration, ``sync.toml``
    (when there is one: adding, changing or removing it makes the set again), the pose folder
    (``pose/``, when there is one) and every candidate camera source in it but mvm's own output
    folders (with their marker; ``-o RIG/results`` holds a ``recap.json``). Empty when ``rig_dir``
    is not a folder (reading it then fails with its own message)."""
    rig_dir = Path(rig_dir)
    if not rig_dir.is_dir():
        return []
    layout = RigLayout(rig_dir)
    inputs = [Path(calib) if calib else find_calibration(rig_dir)]
    if layout.sync.is_file():
        inputs.append(layout.sync)
    if layout.pose_dir.is_dir():
        inputs.append(layout.pose_dir)
    return inputs + [p for p in pose_sources(rig_dir).values() if not is_mvm_output(p)]


def named_inputs(rig_dir: str | Path, paths) -> dict[str, Path]:
    """``paths`` by name for a record (:mod:`mvm.io.provenance`): relative to ``rig_dir`` where
    they lie in it, their full names elsewhere."""
    named = {}
    for path in map(Path, paths):
        try:
            named[path.relative_to(rig_dir).as_posix()] = path
        except ValueError:
            named[str(path)] = path
    return named


def check_rig_output(rig_dir: str | Path, calib: str | Path | None, output: str | Path | None) -> Path:
    """The rig's output folder (``output``, default ``RIG_DIR/mvm``), refused in one line when it
    is, holds or lies inside an input of the rig, or is a non-empty folder mvm did not make
    (:func:`mvm.io.outputs.check_output_location`)."""
    out_dir = Path(output) if output else RigLayout(rig_dir).out_dir
    return check_output_location(out_dir, rig_inputs(rig_dir, calib))


def replace_output_set(build: Callable[[Path], None], path: str | Path, lock_timeout_s: float = LOCK_WAIT_S) -> None:
    """Call ``build(folder)`` to write a complete output set into a fresh folder, then put it in
    place of ``path`` (a folder) in one rename. An exception in ``build`` leaves ``path`` as it
    was and no temporary folder; OS errors and a lock held by another run longer than
    ``lock_timeout_s`` become :class:`~mvm.io.files.OutputError` lines naming ``path``."""
    atomic_replace_dir(build, path, lock_timeout_s=lock_timeout_s)
