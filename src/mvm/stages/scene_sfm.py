"""``sfm``: the camera of every frame, by structure from motion or imported
(:mod:`mvm.video.sfm`): ``sparse/`` and ``sfm/report.json``."""
from __future__ import annotations

from pathlib import Path

from mvm.stages.stage import Done, Job, Stage, present


def _report(job: Job) -> Path:
    return job.layout.sfm_report


def _declared(job: Job) -> tuple[dict, dict]:
    from mvm.video.sfm import camera_inputs

    return camera_inputs(job.scene, job.cameras, job.options.sfm)


def _files(job: Job) -> list[Path]:
    """The report alone: the model in ``sparse/`` is the reconstruction's once it is scaled to
    metres (:mod:`mvm.stages.scene_reconstruct` commits it)."""
    return present(_report(job))


def _reason(job: Job) -> str | None:
    """A camera model without mvm's report was made elsewhere: the clip's input, kept."""
    from mvm.io.provenance import why_redo

    report, sparse = _report(job), job.layout.sparse
    if sparse.is_dir() and not report.is_file():
        return None
    inputs, settings = _declared(job)
    return why_redo(report, inputs, settings, STAGE.title, exists=report.is_file() and sparse.is_dir())


def _run(job: Job, force: bool) -> Done:
    from mvm.video.sfm import import_colmap, import_trajectory, run_sfm

    if job.cameras is None:
        report = run_sfm(job.scene, job.options.sfm, force=force, progress=job.progress)
    elif Path(job.cameras).is_dir():
        report = import_colmap(job.cameras, job.scene, force=force)
    else:
        report = import_trajectory(job.cameras, job.scene, force=force)
    return Done(report, report.why)


STAGE = Stage("sfm", "the camera estimation", ("sfm",), _report, lambda job: _declared(job)[0],
              lambda job: _declared(job)[1], _files, _run, reason=_reason)
