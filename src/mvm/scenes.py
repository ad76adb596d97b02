"""The scene-directory driver: read ``scene/``, reconstruct it (:func:`mvm.core.reconstruct.reconstruct`),
write ``scene/<output>/poses3d.json`` under a lock (the directory contract: docs/architecture.md).

:func:`reconstruct_dir` does one scene; :func:`reconstruct_dirs` does many on the machine's cores
(forked workers, :mod:`mvm.parallel`), each scene's output written (its lock, its fsyncs) while
the next scene is read and computed.
"""
from __future__ import annotations

import itertools
import pickle
import time
from collections.abc import Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict
from functools import partial
from pathlib import Path

from mvm.core.config import Config
from mvm.core.reconstruct import Result, check_affinity_memory, reconstruct, validate_scene
from mvm.errors import InputError
from mvm.io.files import LockTimeout, exclusive_lock, remove_stale_temporaries
from mvm.io.scene_dir import output_dir, poses3d_document, read_scene, write_poses3d
from mvm.parallel import Forked, available_workers, split

#: Fewest scenes worth a worker process of their own (a fork costs about a third of a small scene).
MIN_SCENES_PER_WORKER = 4


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
                     prior=None, workers: int | None = None) -> Iterator[tuple[str | Path, Result | Exception]]:
    """:func:`reconstruct_dir` of every scene of ``paths``, in order: yields ``(path, outcome)``,
    the outcome a :class:`Result` or the exception that scene raised (any ``Exception``: one
    scene's failure is its own, and the next scene is done).

    ``workers`` processes share the scenes (:func:`mvm.parallel.available_workers`: by default
    ``$MVM_WORKERS`` or the cores; ``1`` does everything in this process; at least
    :data:`MIN_SCENES_PER_WORKER` scenes a process). This process does the first contiguous
    share and yields it live; each forked worker reads, computes and writes the next share and
    sends its outcomes once it is done (its log records and warnings are logged here before
    them: :mod:`mvm.parallel`). A worker that dies without answering (or cannot be started) has
    its share done here: no scene is lost. The files, the outcomes and their order are those of
    one process.

    In each process one writer thread writes a scene's ``poses3d.json`` while the next scene is
    read and computed (writing waits on the disk: the fsyncs of
    :func:`mvm.io.files.atomic_write_bytes`); a scene is yielded once its file is written, so
    that its outcome is final.
    """
    config = config or Config()
    paths = list(paths)
    shares = split(len(paths), available_workers(workers), MIN_SCENES_PER_WORKER)
    if len(shares) < 2:
        yield from _stream(paths, config, output, prior)
        return
    first = _attempt(paths[0], config, output, prior)     # imports and caches loaded once, before the fork
    work = partial(_share, config=config, output=output, prior=prior)
    children = []
    try:                                                  # forked before this call starts its writer thread
        for r in shares[1:]:
            children.append(Forked(work, paths[r.start:r.stop]))     # done here if no process can be had
        yield from _stream(paths[1:shares[0].stop], config, output, prior, first)
        for child in children:
            yield from child.result()
    finally:
        for child in children:
            child.stop()


def _stream(paths: list, config: Config, output: str, prior, first: tuple | None = None) -> Iterator[tuple]:
    """``(path, outcome)`` of ``first`` (an :func:`_attempt` already made) and of ``paths``, in
    order, one writer thread writing a scene's file while the next one is computed."""
    attempts = (_attempt(path, config, output, prior) for path in paths)
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="mvm-writer") as writer:
        pending = None
        for path, outcome, out_dir, document in itertools.chain([first] if first else [], attempts):
            write = writer.submit(_write, out_dir, document, config) if document is not None else None
            if pending is not None:
                yield _finished(*pending)
            pending = (path, outcome, write)
        if pending is not None:
            yield _finished(*pending)


def _attempt(path, config: Config, output: str, prior) -> tuple:
    """``(path, result, output folder, document)`` of one scene, or ``(path, exception, None, None)``."""
    try:
        return (path, *_compute(Path(path), config, output, prior))
    except Exception as e:                                # noqa: BLE001 - this scene's failure, reported in order
        return path, e, None, None


def _share(paths: list, config: Config, output: str, prior) -> list[tuple]:
    """A worker's scenes: ``[(path, outcome)]``, every scene done and written as :func:`_stream`
    does, exceptions made fit to be sent back."""
    return [(path, _sendable(outcome)) for path, outcome in _stream(paths, config, output, prior)]


def _sendable(outcome):
    """``outcome``, or for an exception that does not survive pickling one that says the same."""
    if isinstance(outcome, Exception):
        try:
            pickle.loads(pickle.dumps(outcome))
        except Exception:                                 # noqa: BLE001 - any exception may fail to pickle
            return RuntimeError(f"{type(outcome).__name__}: {outcome}")
    return outcome


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
