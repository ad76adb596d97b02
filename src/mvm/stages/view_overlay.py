"""``overlay``: every frame's 2D poses and the reprojected 3D poses drawn on the images
(:func:`mvm.report.write_overlays` of a scene: a ``.mp4`` or a folder of images;
:func:`mvm.report.rig_overlay.write_rig_overlays` of a rig: one video per camera), its record
beside the video or the folder (:mod:`mvm.stages.view`); kept while what it is drawn from (a
rig's videos too) and its settings are unchanged."""
from __future__ import annotations

from pathlib import Path

from mvm.io.layout import OVERLAY
from mvm.stages.stage import Done, Stage
from mvm.stages.view import (
    ViewJob,
    camera_videos,
    check_record_name,
    input_paths,
    list_in_output_set,
    load_rig_view,
    not_reconstructed,
    view_inputs,
)

#: The stage in the reasons of a rerun.
TITLE = "the overlay"
#: A folder of images keeps its record inside it, as ``overlay.inputs.json``.
FOLDER_RECORD = OVERLAY


def target(job: ViewJob) -> Path:
    return Path(job.out) if job.out is not None else job.out_dir / OVERLAY


def _folder(job: ViewJob) -> bool:
    """Whether a scene's overlay is a folder of images (replaced whole, its record inside it)."""
    return not job.rig and target(job).suffix.lower() != ".mp4"


def _record(job: ViewJob) -> Path:
    """The output whose record says what the overlay was drawn from: the video (record beside
    it), or :data:`FOLDER_RECORD` inside a folder of images, so that nothing lands beside a
    folder the user named."""
    return target(job) / FOLDER_RECORD if _folder(job) else target(job)


def _exists(job: ViewJob) -> bool | None:
    """Whether a folder of images is there (its record alone does not say); None: a video."""
    return target(job).is_dir() if _folder(job) else None


def _reason(job: ViewJob) -> str | None:
    from mvm.io.provenance import why_redo

    return why_redo(_record(job), _inputs(job), _settings(job), TITLE, exists=_exists(job))


def _inputs(job: ViewJob) -> dict:
    return view_inputs(job, videos=True)


def _settings(job: ViewJob) -> dict:
    if job.rig:
        return {"calib": str(job.calib) if job.calib else None, "step": job.step, "max_width": job.max_width}
    return {"step": job.step, "max_width": job.max_width, "fps": job.fps, "image_format": job.image_format}


def _files(job: ViewJob) -> list[Path]:
    from mvm.io.provenance import record_path

    path = target(job)
    if path.is_dir():
        return sorted(p for p in path.iterdir() if p.is_file() and not p.name.startswith(".")
                      and p.name != record_path(path / FOLDER_RECORD).name)
    return [path] if path.is_file() else []


def _run(job: ViewJob, force: bool) -> Done:
    """``Done.result``: what the overlay wrote (``OverlaySummary`` of a scene,
    ``RigOverlaySummary`` of a rig), or None when it was kept."""
    from mvm.io.outputs import check_output_location
    from mvm.io.provenance import produce

    out, inputs, folder = target(job), _inputs(job), _folder(job)
    paths = input_paths(inputs)
    if folder:                                  # replaced whole: never a folder holding what mvm did not write
        check_output_location(out, paths)
    check_record_name(_record(job), inputs, TITLE)

    def make(why: str, hashed: dict):
        if job.rig:
            from mvm.report.rig_overlay import rig_overlay_target, write_rig_overlays

            check_output_location(rig_overlay_target(job.out_dir, job.out, job.step), paths)   # before any reading
            data = load_rig_view(job)
            summary = write_rig_overlays(data, camera_videos(job, data.names), paths, job.out, job.step, job.max_width)
            list_in_output_set(job, out)
            return summary
        from mvm.io.outputs import add_to_output_set
        from mvm.io.provenance import record_path
        from mvm.report import write_overlays

        summary = write_overlays(Path(job.folder), job.out, output=job.output, step=job.step, max_width=job.max_width,
                                 fps=job.fps, image_format=job.image_format)
        if folder:                              # the record, written next, is the folder's own
            add_to_output_set(out, record_path(_record(job)).name, lambda path: None)
        return summary

    summary, why = produce(_record(job), TITLE, inputs, _settings(job), make, None, force=force,
                           exists=_exists(job))
    return Done(summary, why)


STAGE = Stage("overlay", TITLE, (), _record, _inputs, _settings, _files, _run, reason=_reason,
              applies=not_reconstructed)
