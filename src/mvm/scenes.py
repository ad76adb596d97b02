"""The scene-directory driver: read ``scene/``, reconstruct it (:func:`mvm.core.reconstruct.reconstruct`),
write ``scene/<output>/poses3d.json`` under a lock (the directory contract: docs/architecture.md).

:func:`reconstruct_dir` does one scene; :func:`reconstruct_dirs` does many, each scene's output
written (its lock, its fsyncs) while the next scene is read and computed.
"""
from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict
from pathlib import Path

from mvm.core.config import Config
from mvm.core.reconstruct import Result, check_affinity_memory, reconstruct, validate_scene
from mvm.errors import InputError
from mvm.io.files import LockTimeout, exclusive_lock, remove_stale_temporaries
from mvm.io.scene_dir import output_dir, poses3d_document, read_scene, write_poses3d


def reconstruct_dir(path: str | Path, config: Config | None = None, output: str = "mvm",
                    prior=None) -> Result:
    """Read a scene directory, reconstruct it and write ``<path>/<output>/poses3d.json``.

    Bad input raises :class:`~mvm.errors.InputError` naming the file before anything is written.
    """
    config = config or Config()
    result, out_dir, document = _compute(Path(path), config, output, prior)
    _write(out_dir, document, config)
    return result


def reconstruct_dirs(paths: Iterable[str | Path], config: Config | None = None, output: str = "mvm",
                     prior=None) -> Iterator[tuple[str | Path, Result | Exception]]:
    """:func:`reconstruct_dir` of every scene of ``paths``, in order: yields ``(path, outcome)``,
    the outcome a :class:`Result` or the exception that scene raised (any ``Exception``: one
    scene's failure is its own, and the next scene is done).

    One writer thread writes a scene's ``poses3d.json`` while the next scene is read and
    computed (writing waits on the disk: the fsyncs of :func:`mvm.io.files.atomic_write_bytes`);
    a scene is yielded once its file is written, so that its outcome is final. The files are the
    same as :func:`reconstruct_dir`'s, written one at a time in the order of ``paths``.
    """
    config = config or Config()
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="mvm-writer") as writer:
        pending = None
        for path in paths:
            try:
                result, out_dir, document = _compute(Path(path), config, output, prior)
                current = (path, result, writer.submit(_write, out_dir, document, config))
            except Exception as e:                      # this scene's failure, reported in order
                current = (path, e, None)
            if pending is not None:
                yield _finished(*pending)
            pending = current
        if pending is not None:
            yield _finished(*pending)


def _finished(path, outcome, write: Future | None) -> tuple:
    """``(path, outcome)`` once the scene's file is written (its write error as the outcome)."""
    if write is not None:
        try:
            write.result()
        except Exception as e:
            return path, e
    return path, outcome


def _compute(path: Path, config: Config, output: str, prior) -> tuple[Result, Path, dict]:
    """Read and reconstruct one scene: its result, output folder and ``poses3d.json`` document."""
    t = time.perf_counter()
    scene = read_scene(path)
    out_dir = output_dir(path, output)
    read_s = time.perf_counter() - t
    validate_scene(scene, str(path))
    check_affinity_memory(len(scene.poses), config.use_appearance and scene.poses.appearance is not None,
                          config, str(path / "poses2d.json"))
    result = reconstruct(scene, config, prior)
    result.timings = {"read_s": read_s, **result.timings}
    document = poses3d_document(result.persons, scene.poses, result.metrics,
                                {"warnings": list(result.warnings),
                                 "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
                                 "config": asdict(config)})
    return result, out_dir, document


def _write(out_dir: Path, document: dict, config: Config) -> None:
    """Write ``out_dir/poses3d.json``. Runs on the same scene may compute at once; writing is
    one at a time, and the temporary files of a killed run are removed by the next one."""
    try:
        with exclusive_lock(out_dir, config.lock_timeout_s):
            remove_stale_temporaries(out_dir, "poses3d.json")
            write_poses3d(out_dir / "poses3d.json", document)
    except LockTimeout:
        raise InputError(out_dir, None, f"another mvm run has been writing here for more than "
                                        f"{config.lock_timeout_s:g} s (lock_timeout_s)") from None
