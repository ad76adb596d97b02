"""``detect``: the 2D poses and appearance of every frame, detected or imported
(:mod:`mvm.video.detect`): ``poses2d.json``."""
from __future__ import annotations

from pathlib import Path

from mvm.errors import InputError
from mvm.stages.stage import Done, Job, Stage, present


def _poses2d(job: Job) -> Path:
    return job.layout.poses2d


def detector_of(job: Job) -> tuple[str, Path | None, str | None]:
    """``(detector, detections, checkpoint)`` of ``job``: the detector the ``[detect]`` table
    names (``rtmo``, ``rtmpose``, ``yolo-pose``: the clip's imported detections are not used),
    else the network when a checkpoint is given, else the clip's imported detections."""
    options = job.options
    if options.detect.detector not in (None, "import", "mvm"):
        return options.detect.detector, None, None
    if options.checkpoint is not None:
        return "mvm", None, options.checkpoint
    return "import", job.detections, None


def _declared(job: Job) -> tuple[dict, dict]:
    from mvm.io.pose_format import pose_format
    from mvm.video.detect import detect_inputs, detect_settings, registered_names

    kind, source, checkpoint = detector_of(job)
    fmt = (job.detections_format or pose_format(source)[0]) if source is not None else None
    return (detect_inputs(job.scene, registered_names(job.scene), source, checkpoint),
            detect_settings(kind, fmt, job.options.detect))


def _reason(job: Job) -> str | None:
    """2D poses without a record were made elsewhere: the clip's input, kept; so are 2D poses
    imported earlier when the clip no longer has detections to import."""
    from mvm.io.provenance import read_record, why_redo

    out = _poses2d(job)
    if out.is_file() and read_record(out) is None:
        return None
    kind, source, _ = detector_of(job)
    if kind == "import" and source is None:
        return "no output yet" if not out.is_file() else None
    inputs, settings = _declared(job)
    return why_redo(out, inputs, settings, STAGE.title)


def _run(job: Job, force: bool) -> Done:
    from mvm.video.detect import detect_scene

    kind, source, checkpoint = detector_of(job)
    if kind == "import" and source is None:
        raise InputError(job.scene, "detect", "no 2D poses: give --checkpoint, or put detections.json or "
                                              "detections/ in the scene directory")
    found = detect_scene(job.scene, source, checkpoint, job.detections_format if source is not None else None,
                         job.options.detect, force=force, progress=job.tick("detect"))
    return Done(found, found.why)


STAGE = Stage("detect", "the detection", ("detect",), _poses2d, lambda job: _declared(job)[0],
              lambda job: _declared(job)[1], lambda job: present(_poses2d(job)), _run, reason=_reason)
