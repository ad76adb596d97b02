"""``overlay``: every frame's 2D poses and the reprojected 3D poses drawn on the images
(:func:`mvm.report.write_overlays` of a scene: a ``.mp4`` or a folder of images;
:func:`mvm.report.rig_overlay.write_rig_overlays` of a rig: one video per camera), its record
beside the video or the folder (:mod:`mvm.stages.view`); kept while what it is drawn from (a
rig's videos too) and its settings are unchanged."""
from __future__ import annotations

from pathlib import Path

from mvm.stages.stage import Done, Stage
from mvm.stages.view import ViewJob, check_record_name, list_in_output_set, not_reconstructed, view_inputs

#: The stage in the reasons of a rerun.
TITLE = "the overlay"


def _target(job: ViewJob) -> Path:
    from mvm.report.rig_overlay import OVERLAY_NAME

    return Path(job.out) if job.out is not None else job.out_dir / OVERLAY_NAME


def _inputs(job: ViewJob) -> dict:
    return view_inputs(job, videos=True)


def _settings(job: ViewJob) -> dict:
    if job.rig:
        return {"calib": str(job.calib) if job.calib else None, "step": job.step, "max_width": job.max_width}
    return {"step": job.step, "max_width": job.max_width, "fps": job.fps, "image_format": job.image_format}


def _files(job: ViewJob) -> list[Path]:
    target = _target(job)
    if target.is_dir():
        return sorted(p for p in target.iterdir() if p.is_file() and not p.name.startswith("."))
    return [target] if target.is_file() else []


def _run(job: ViewJob, force: bool) -> Done:
    """``Done.result``: what the overlay wrote (``OverlaySummary`` of a scene,
    ``RigOverlaySummary`` of a rig), or None when it was kept."""
    from mvm.io.provenance import produce

    target, inputs = _target(job), _inputs(job)
    check_record_name(target, inputs, TITLE)

    def make(why: str, hashed: dict):
        if job.rig:
            from mvm.report.rig_overlay import write_rig_overlays

            summary = write_rig_overlays(Path(job.folder), job.out, output=job.output, calib=job.calib, step=job.step,
                                         max_width=job.max_width)
            list_in_output_set(job, target)
            return summary
        from mvm.report import write_overlays

        return write_overlays(Path(job.folder), job.out, output=job.output, step=job.step, max_width=job.max_width,
                              fps=job.fps, image_format=job.image_format)

    summary, why = produce(target, TITLE, inputs, _settings(job), make, None, force=force)
    return Done(summary, why)


STAGE = Stage("overlay", TITLE, (), _target, _inputs, _settings, _files, _run, applies=not_reconstructed)
