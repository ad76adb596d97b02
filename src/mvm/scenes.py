"""The scene-directory driver: read ``scene/``, reconstruct it (:func:`mvm.core.reconstruct.reconstruct_many`),
write ``scene/<output>/poses3d.json`` under a lock (the directory contract: docs/architecture.md).

:func:`reconstruct_dir` does one scene; :func:`reconstruct_dirs` does many on the machine's cores
(forked workers, :mod:`mvm.parallel`), small scenes a batch at a time, each batch's outputs
written (their locks, their fsyncs) while the next batch is read and computed.
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
from mvm.core.reconstruct import Result, check_affinity_memory, reconstruct_many, scene_config, validate_scene
from mvm.io.files import atomic_write_json
from mvm.io.layout import DEFAULT_OUTPUT, POSES2D, POSES3D, TIMINGS
from mvm.io.provenance import fingerprints, produce
from mvm.io.scene_dir import (
    RECONSTRUCT_STAGE,
    output_dir,
    poses3d_document,
    read_scene,
    reconstruct_settings,
    reconstruction_inputs,
    write_poses3d,
)
from mvm.parallel import Forked, available_workers, split

#: Fewest scenes worth a worker process of their own (a fork costs about a third of a small scene).
MIN_SCENES_PER_WORKER = 4
#: Most scenes reconstructed together (:func:`mvm.core.reconstruct.reconstruct_many`).
BATCH_SCENES = 32
#: A batch is closed once its scenes hold this many 2D poses, or this many sparse 3D points
#: (a large scene is a batch of its own: its results come as soon as it is done, and a batch
#: holds little memory).
BATCH_POSES, BATCH_POINTS = 1000, 100_000


def reconstruct_dir(path: str | Path, config: Config | None = None, output: str = DEFAULT_OUTPUT,
                    prior=None) -> Result:
    """Read a scene directory, reconstruct it and write ``<path>/<output>/poses3d.json``.

    Bad input raises :class:`~mvm.errors.InputError` naming the file before anything is written.
    """
    config = scene_config(config)
    [(_, outcome, out_dir, document)] = _reconstructed([_read(Path(path), config, output)], config, prior)
    if isinstance(outcome, Exception):
        raise outcome
    _write(out_dir, document, config)
    return outcome


def reconstruct_read(path: str | Path, config: Config, output: str = DEFAULT_OUTPUT,
                     prior=None) -> tuple[Result, object]:
    """Read the scene directory ``path`` and reconstruct it, writing nothing: ``(result, scene)``
    (``config`` already the scene driver's, :func:`~mvm.core.reconstruct.scene_config`). The
    scene stage of :mod:`mvm.stages` writes the result itself (:func:`result_document`)."""
    assert config.resolved, "reconstruct_read takes the scene driver's settings (scene_config)"
    read = _read(Path(path), config, output, hashed=False)            # the stage's writer hashed them
    if isinstance(read[1], Exception):
        raise read[1]
    [outcome] = reconstruct_many([read[1]], config, prior)
    if isinstance(outcome, Exception):
        raise outcome
    outcome.timings = {"read_s": read[3], **outcome.timings}
    return outcome, read[1]


def result_document(result: Result, scene, config: Config, extra: dict | None = None) -> dict:
    """The ``poses3d.json`` document of ``result`` (of ``scene``, reconstructed with ``config``):
    the persons, the metrics, the warnings, the settings and ``extra`` (the metric scale).
    Nothing in it depends on the run (its seconds go to ``timings.json``, :func:`write_result`),
    so that the same scene gives the same bytes."""
    return poses3d_document(result.persons, scene.poses, result.metrics,
                            {"warnings": list(result.warnings), "config": asdict(config), **(extra or {})})


def write_result(out_dir: Path, document: dict, timings: dict) -> None:
    """Write ``out_dir/poses3d.json`` and the seconds its reconstruction took
    (``out_dir/timings.json``), each atomically; the caller holds the output's lock."""
    write_poses3d(out_dir / POSES3D, document)
    atomic_write_json(out_dir / TIMINGS, {k: round(v, 4) for k, v in timings.items()}, pretty=True)


def reconstruct_dirs(paths: Iterable[str | Path], config: Config | None = None, output: str = DEFAULT_OUTPUT,
                     prior=None, workers: int | None = None) -> Iterator[tuple[str | Path, Result | Exception]]:
    """:func:`reconstruct_dir` of every scene of ``paths``, in order: yields ``(path, outcome)``,
    the outcome a :class:`Result` or the exception that scene raised (any ``Exception``: one
    scene's failure is its own, and the next scene is done).

    Scenes are read one by one and reconstructed a batch at a time
    (:func:`mvm.core.reconstruct.reconstruct_many`: one refinement solve for the batch, the
    numbers of one scene at a time to rounding): up to :data:`BATCH_SCENES` scenes, fewer once
    their 2D poses reach :data:`BATCH_POSES` or their sparse points :data:`BATCH_POINTS`.

    ``workers`` processes share the scenes (:func:`mvm.parallel.available_workers`: by default
    ``$MVM_WORKERS`` or the cores; ``1`` does everything in this process; at least
    :data:`MIN_SCENES_PER_WORKER` scenes a process). This process does the first contiguous
    share and yields it live; each forked worker reads, computes and writes the next share and
    sends its outcomes once it is done (its log records and warnings are logged here before
    them: :mod:`mvm.parallel`). A worker that dies without answering (or cannot be started) has
    its share done here: no scene is lost. The files, the outcomes and their order are those of
    one process.

    In each process one writer thread writes a batch's ``poses3d.json`` files while the next
    batch is read and computed (writing waits on the disk: the fsyncs of
    :func:`mvm.io.files.atomic_write_bytes`); a scene is yielded once its file is written, so
    that its outcome is final.
    """
    config = scene_config(config)
    paths = list(paths)
    shares = split(len(paths), available_workers(workers), MIN_SCENES_PER_WORKER)
    if len(shares) < 2:
        yield from _stream(paths, config, output, prior)
        return
    first = _reconstructed([_read(Path(paths[0]), config, output)], config, prior)   # imports and caches
    work = partial(_share, config=config, output=output, prior=prior)                # loaded once, before the fork
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


def _stream(paths: list, config: Config, output: str, prior, first: list | None = None) -> Iterator[tuple]:
    """``(path, outcome)`` of ``first`` (a batch :func:`_reconstructed` already made) and of
    ``paths``, in order, one writer thread writing a batch's files while the next is computed."""
    batches = itertools.chain([first] if first else [], _batches(paths, config, output, prior))
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="mvm-writer") as writer:
        pending: list = []
        for batch in batches:
            writes = [(path, outcome, writer.submit(_write, out_dir, document, config) if document is not None
                       else None) for path, outcome, out_dir, document in batch]
            yield from (_finished(*p) for p in pending)
            pending = writes
        yield from (_finished(*p) for p in pending)


def _batches(paths: list, config: Config, output: str, prior) -> Iterator[list[tuple]]:
    """The scenes of ``paths`` read one by one and reconstructed a batch at a time: lists of
    ``(path, outcome, output folder, document)`` (:func:`_reconstructed`)."""
    batch, poses, points = [], 0, 0
    for path in paths:
        batch.append(_read(Path(path), config, output))
        scene = batch[-1][1]
        if not isinstance(scene, Exception):
            poses, points = poses + len(scene.poses), points + len(scene.points3d)
        if len(batch) >= BATCH_SCENES or poses >= BATCH_POSES or points >= BATCH_POINTS:
            yield _reconstructed(batch, config, prior)
            batch, poses, points = [], 0, 0
    if batch:
        yield _reconstructed(batch, config, prior)


def _read(path: Path, config: Config, output: str, hashed: bool = True) -> tuple:
    """``(path, scene, output folder, seconds to read, fingerprints)`` of a scene read and
    checked, or ``(path, exception, None, None, None)``; the fingerprints of its inputs
    (:mod:`mvm.io.provenance`), taken once the guarded readers accepted them, are for the
    output's record (None without ``hashed``: the caller took them)."""
    try:
        t = time.perf_counter()
        scene = read_scene(path)
        hashed = fingerprints(reconstruction_inputs(path)) if hashed else None
        out_dir = output_dir(path, output)
        read_s = time.perf_counter() - t
        validate_scene(scene, str(path))
        check_affinity_memory(scene, config, str(path / POSES2D))
        return path, scene, out_dir, read_s, hashed
    except Exception as e:                                # noqa: BLE001 - this scene's failure, reported in order
        return path, e, None, None, None


def _reconstructed(batch: list[tuple], config: Config, prior) -> list[tuple]:
    """``(path, result, output folder, what to write)`` of each scene :func:`_read` in
    ``batch``, reconstructed together (what to write: the ``poses3d.json`` document, the seconds,
    the scene and the fingerprints of its inputs, for :func:`_write`), or ``(path, exception,
    None, None)``."""
    scenes = [scene for _, scene, _, _, _ in batch if not isinstance(scene, Exception)]
    results = iter(reconstruct_many(scenes, config, prior))
    out = []
    for path, scene, out_dir, read_s, hashed in batch:
        outcome = scene if isinstance(scene, Exception) else next(results)
        if isinstance(outcome, Exception):
            out.append((path, outcome, None, None))
            continue
        try:
            outcome.timings = {"read_s": read_s, **outcome.timings}
            document = result_document(outcome, scene, config)
            out.append((path, outcome, out_dir, (document, outcome.timings, path, hashed)))
        except Exception as e:                            # noqa: BLE001 - this scene's failure, reported in order
            out.append((path, e, None, None))
    return out


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


def _write(out_dir: Path, made: tuple, config: Config) -> None:
    """Write ``out_dir/poses3d.json`` and its record (``made``: the document, the seconds, the
    scene and its fingerprints). Runs on the same scene may compute at once; writing is one at
    a time (:func:`mvm.io.provenance.produce`'s lock), and the temporary files of a killed run
    are removed by the next one."""
    document, timings, scene, hashed = made
    produce(out_dir / POSES3D, RECONSTRUCT_STAGE, reconstruction_inputs(scene),
            reconstruct_settings(config, metric_scale=False), lambda why, _: write_result(out_dir, document, timings),
            None, force=True, lock=out_dir / POSES3D, lock_timeout_s=config.lock_timeout_s, hashed=hashed)
