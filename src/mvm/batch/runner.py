"""The driver of ``mvm batch``: claims (clip, stage) work in the manifest, hands it to an
engine, commits what comes back, retries transient failures, and merges the training set.

The driver alone writes the manifest; workers only run stages and report. A cluster's workers
then need no access to the database (SQLite's locking is unreliable on network file systems),
and the one writer never waits on a lock held by a worker. Runs of several drivers on the same
root stay safe: every claim is a ``BEGIN IMMEDIATE`` transaction that takes only pending or
failed work, so two drivers share the clips instead of doing them twice.
"""
from __future__ import annotations

import logging
import os
import socket
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from mvm.batch.clips import Clip, discover_clips
from mvm.batch.engines import make_engine
from mvm.batch.manifest import Manifest
from mvm.batch.stages import (
    STAGES,
    BatchOptions,
    StageResult,
    checksum,
    clip_stats,
    not_applicable,
    one_line,
    output_files,
    stage_reason,
)
from mvm.errors import InputError
from mvm.io.layout import DEFAULT_OUTPUT, SUPERVISION_FILE, SceneLayout

log = logging.getLogger(__name__)

TRAINING_SET = Path(".mvm") / "training" / "annotations.json"
HEARTBEAT_S = 10.0


@dataclass
class Progress:
    """Counts of a run so far, given to the progress callback."""

    clips: int
    done: int = 0
    failed: int = 0
    elsewhere: int = 0
    running: int = 0
    seconds: float = 0.0
    last: str = ""

    @property
    def per_second(self) -> float:
        return (self.done + self.failed) / self.seconds if self.seconds > 0 else 0.0


@dataclass
class BatchSummary:
    """What a run did. ``failed``: (clip, stage, error); ``stage_seconds``: worker seconds
    per stage; ``committed``: stages committed by this run; ``training_set``: the merged
    supervision (None when ``export`` did not run)."""

    run: int
    engine: str
    workers: int
    clips: int
    done: int
    failed: list[tuple[str, str, str]]
    elsewhere: int
    seconds: float
    committed: int
    retried: int
    recovered: int
    stage_seconds: dict = field(default_factory=dict)
    training_set: Path | None = None
    #: (clip, stage, why) of each stage done before and redone by this run, as its inputs or
    #: settings changed (or ``forced``).
    redone: list[tuple[str, str, str]] = field(default_factory=list)

    @property
    def clips_per_second(self) -> float:
        return (self.done + len(self.failed)) / self.seconds if self.seconds > 0 else 0.0


def parse_stages(text: str | None) -> tuple[str, ...]:
    """``"sfm,detect"`` -> ``("sfm", "detect")`` in pipeline order; None: every stage."""
    if not text:
        return STAGES
    names = [s.strip() for s in text.split(",") if s.strip()]
    unknown = [s for s in names if s not in STAGES]
    if unknown or not names:
        raise InputError(None, "--stages", f"unknown stage {unknown[0] if unknown else text!r}: "
                                           f"expected a comma-separated list of {', '.join(STAGES)}")
    return tuple(s for s in STAGES if s in names)


class _Driver:
    def __init__(self, root: Path, clips: list[Clip], stages: tuple[str, ...], manifest: Manifest, run: int,
                 engine, options: BatchOptions, retries: int, progress: Progress,
                 on_progress: Callable[[Progress], None] | None, force: bool = False):
        self.root, self.stages, self.manifest, self.run = root, stages, manifest, run
        self.engine, self.options, self.retries = engine, options, retries
        self.clips = {c.id: c for c in clips}
        self.cursor = {c.id: 0 for c in clips}
        self.queue = deque(c.id for c in clips)
        self.attempts: dict[tuple[str, str], int] = {}
        self.in_flight = 0
        self.progress, self.on_progress = progress, on_progress
        self.failed: list[tuple[str, str, str]] = []
        self.committed = self.retried = 0
        self.stage_seconds = {s: 0.0 for s in stages}
        self.force = force
        #: (clip, stage) this run has found up to date or committed: not looked at again.
        self.settled: set[tuple[str, str]] = set()
        self.redone: list[tuple[str, str, str]] = []

    def _skip_present(self, clip: Clip, stage: str) -> None:
        files = output_files(clip, stage, self.options)
        stats = clip_stats(clip.scene, self.options.output) if stage in ("reconstruct", "export") else None
        self.manifest.skip(self.run, clip.id, stage, "present: outputs up to date", stats,
                           checksum(clip.scene, files) if files else None, len(files))

    def next_stage(self, cid: str) -> str | None:
        """Claim the clip's next stage to run; None when the clip is finished, failed (or held
        elsewhere). Any error while looking at the clip's files (a corrupt ``poses3d.json``
        beside its outputs, a link that leads out) is the clip's failure, never the run's."""
        try:
            return self._next_stage(cid)
        except Exception as e:  # noqa: BLE001 - the clip fails, the others go on
            stage = self.stages[self.cursor[cid]] if self.cursor[cid] < len(self.stages) else self.stages[-1]
            self._fail_clip(cid, stage, e)
            return None

    def _fail_clip(self, cid: str, stage: str, error: BaseException) -> None:
        """Record ``error`` as the failure of (clip, stage) found by the driver itself."""
        result = StageResult(cid, stage, ok=False, error=one_line(error), pid=os.getpid(), host=socket.gethostname())
        if self.manifest.state(cid, stage) != "running":
            self.manifest.claim(self.run, cid, stage)
        self.manifest.fail(self.run, result, retry=False)
        self.failed.append((cid, stage, result.error))
        self.progress.failed += 1
        self.progress.last = cid
        log.warning("%s: %s: %s", cid, stage, result.error)

    def _next_stage(self, cid: str) -> str | None:
        """The clip's first stage not settled in this run: kept when its outputs are up to date
        (:func:`~mvm.batch.stages.stage_reason`), else claimed; a stage done by an earlier run
        whose inputs or settings changed (or every stage with ``force``) is opened again, and
        with it, through their inputs, the stages after it."""
        clip = self.clips[cid]
        while self.cursor[cid] < len(self.stages):
            stage = self.stages[self.cursor[cid]]
            if (cid, stage) in self.settled:
                self.cursor[cid] += 1
                continue
            state = self.manifest.state(cid, stage)
            if state == "running":
                self.progress.elsewhere += 1
                return None
            reason = not_applicable(clip, stage)
            if reason is not None:
                if state not in ("done", "skipped"):
                    self.manifest.skip(self.run, cid, stage, reason)
                self.settled.add((cid, stage))
                continue
            why = "forced" if self.force else stage_reason(clip, stage, self.options)
            if why is None:
                if state not in ("done", "skipped"):
                    self._skip_present(clip, stage)
                self.settled.add((cid, stage))
                continue
            if state in ("done", "skipped"):
                self.manifest.reopen(self.run, cid, stage, why)
                self.redone.append((cid, stage, why))
                log.info("%s: %s: redone: %s", cid, stage, why)
            if self.manifest.claim(self.run, cid, stage):
                return stage
            self.progress.elsewhere += 1
            return None
        self.progress.done += 1
        self.progress.last = cid
        return None

    def fill(self) -> None:
        while self.queue and self.in_flight < self.engine.capacity:
            cid = self.queue.popleft()
            stage = self.next_stage(cid)
            if stage is not None:
                self.engine.submit(self.clips[cid], stage, self.force)
                self.in_flight += 1
                self.attempts[cid, stage] = self.attempts.get((cid, stage), 0) + 1

    def handle(self, result: StageResult) -> None:
        self.in_flight -= 1
        key = (result.clip, result.stage)
        self.stage_seconds[result.stage] += result.seconds
        if result.ok:
            if self.manifest.commit(self.run, result):
                self.committed += 1
                self.settled.add(key)
                self.queue.appendleft(result.clip)      # the clip's next stage goes first
            else:
                self.progress.elsewhere += 1
            return
        retry = result.transient and self.attempts[key] <= self.retries
        self.manifest.fail(self.run, result, retry)
        if retry:
            self.retried += 1
            log.warning("%s: %s: %s (retrying, attempt %d of %d)", result.clip, result.stage, result.error,
                        self.attempts[key] + 1, self.retries + 1)
            self.queue.appendleft(result.clip)
        else:
            self.failed.append((result.clip, result.stage, result.error or "failed"))
            self.progress.failed += 1
            self.progress.last = result.clip

    def loop(self, started: float) -> None:
        beat = time.monotonic()
        self.fill()
        while self.in_flight or self.queue:
            for result in self.engine.poll(timeout=0.5):
                self.handle(result)
            self.fill()
            if time.monotonic() - beat > HEARTBEAT_S:
                self.manifest.heartbeat(self.run)
                beat = time.monotonic()
            self.progress.running = self.in_flight
            self.progress.seconds = time.perf_counter() - started
            if self.on_progress:
                self.on_progress(self.progress)


def merge_training_set(root: str | Path, manifest: Manifest, output: str = DEFAULT_OUTPUT,
                       on_bad_clip: Callable[[str, InputError], None] | None = None) -> Path | None:
    """Merge every exported clip's supervision into ``ROOT/.mvm/training/annotations.json``.
    A clip whose supervision cannot be read or is inconsistent is left out and reported to
    ``on_bad_clip`` (clip id, the error); the others are merged."""
    from mvm.net.supervision import merge_datasets

    root = Path(root)
    done = {r["clip"] for r in manifest.stages() if r["stage"] == "export" and r["state"] in ("done", "skipped")}
    clip_of = {}
    for clip in manifest.clips():
        path = SceneLayout(clip["scene"], output).supervision / SUPERVISION_FILE
        if clip["id"] in done and path.is_file():
            clip_of[path] = clip["id"]
    if not clip_of:
        return None

    def bad(path: Path, error: InputError) -> None:
        log.warning("%s: left out of the training set: %s", clip_of[path], error)
        if on_bad_clip is not None:
            on_bad_clip(clip_of[path], error)

    return merge_datasets(list(clip_of), root / TRAINING_SET, on_bad_source=bad)


def run_batch(root: str | Path, stages: tuple[str, ...] = STAGES, engine: str = "local", workers: int | None = None,
              address: str | None = None, retries: int = 2, options: BatchOptions | None = None,
              on_progress: Callable[[Progress], None] | None = None, force: bool = False) -> BatchSummary:
    """Run ``stages`` on every clip of ``root`` that has not done them, recording each
    (clip, stage) in ``ROOT/.mvm/manifest.sqlite``. A stage done before is done again when its
    inputs or settings changed since (the records of :mod:`mvm.io.provenance`; the summary's
    ``redone`` says why), and so are the stages whose inputs it changes.

    Args:
        root: videos and scene directories (:mod:`mvm.batch.clips`).
        stages: names from :data:`STAGES`, run in pipeline order per clip.
        engine: ``"local"`` (a process pool of ``workers``, default all cores) or ``"ray"``
            (a local Ray instance with ``workers`` CPUs, or the cluster at ``address``).
        retries: further attempts of a stage after a transient failure (a lost worker, an
            OS error); bad input fails at once.
        options: the stages' settings (default :class:`BatchOptions`).
        on_progress: called with :class:`Progress` as the run advances.
        force: redo every stage of every clip, whatever the records of their outputs say.
    Returns:
        :class:`BatchSummary`. A failed clip is recorded with its error; the others go on.
    """
    root = Path(root)
    options = options or BatchOptions()
    if retries < 0:
        raise InputError(None, "--retries", f"expected a count >= 0, got {retries}")
    clips = discover_clips(root)
    manifest = Manifest(root)
    started = time.perf_counter()
    eng = make_engine(engine, workers, options, address)
    run = manifest.begin_run(engine, eng.capacity, stages)
    outcome = "interrupted"
    try:
        manifest.register(clips, stages)
        recovered = manifest.recover_stale(run)
        if recovered:
            log.warning("%d stage(s) claimed by a run that died go back to pending", len(recovered))
        driver = _Driver(root, clips, stages, manifest, run, eng, options, retries, Progress(len(clips)), on_progress,
                         force)
        driver.loop(started)
        outcome = "finished"
    finally:
        eng.close(wait=outcome == "finished")
        manifest.end_run(run, outcome)
    left_out: list[tuple[str, str, str]] = []
    training = (merge_training_set(root, manifest, options.output,
                                   lambda cid, e: left_out.append((cid, "export",
                                                                   f"left out of the training set: {e}")))
                if "export" in stages else None)
    manifest.close()
    return BatchSummary(run, engine, eng.capacity, len(clips), driver.progress.done, driver.failed + left_out,
                        driver.progress.elsewhere, time.perf_counter() - started, driver.committed,
                        driver.retried, len(recovered), driver.stage_seconds, training, driver.redone)
