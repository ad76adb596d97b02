"""The runner: a clip through a list of stages. Each stage is kept when its outputs are up to
date and made otherwise, through :func:`mvm.io.provenance.produce` (fingerprints of the
inputs, the stale check, the output's lock, the atomic writes, the record); a forced stage
forces the stages after it (a stage made again because its inputs changed is enough for the
next one's record to see its own inputs changed).
"""
from __future__ import annotations

import logging
import time
from collections.abc import Iterable

from mvm.errors import InputError
from mvm.stages.stage import Done, Job, RigJob, Stage

log = logging.getLogger(__name__)


def forced(force, name: str) -> bool:
    """Whether ``force`` (True, ``"all"``, a stage's name or names) names the stage ``name``."""
    if isinstance(force, str):
        return force in ("all", name)
    return force is True or (bool(force) and name in force)


def run_stage(stage: Stage, job: Job | RigJob, force: bool = False) -> Done:
    """Run ``stage`` on ``job`` (a clip, or a rig folder for the rig's stages): its outputs kept
    when up to date, else made (or ``force``)."""
    t = time.perf_counter()
    done = stage.run(job, force)
    done.seconds = time.perf_counter() - t
    log.info("%s: %s: %s", job.folder, stage.name, "kept: up to date" if done.why is None else f"made: {done.why}")
    return done


def run_stages(job: Job, stages: Iterable[Stage], force=()) -> dict[str, Done]:
    """Run ``stages`` on ``job`` in order: ``{name: Done}`` of those that apply.

    ``force``: stage names to redo whatever their records say (True or ``"all"``: every one);
    a forced stage forces the ones after it."""
    stages = list(stages)
    named = (force,) if isinstance(force, str) else () if isinstance(force, bool) else tuple(force)
    unknown = [n for n in named if n != "all" and n not in {s.name for s in stages}]
    if unknown:
        raise InputError(None, "--force", f"unknown stage {unknown[0]!r}: expected one of "
                                          f"{', '.join(s.name for s in stages)}")
    done: dict[str, Done] = {}
    redo = False
    for stage in stages:
        if stage.applies(job) is not None:
            continue
        redo = redo or forced(force, stage.name)
        done[stage.name] = run_stage(stage, job, redo)
    return done
