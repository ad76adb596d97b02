"""``frames``: the video's frames, sampled, blur skipped, kept by camera motion
(:mod:`mvm.video.frames`): ``frames/`` and ``frames.json``."""
from __future__ import annotations

from pathlib import Path

from mvm.stages.stage import Done, Job, Stage


def _inputs(job: Job) -> dict:
    from mvm.video.frames import frame_inputs

    return frame_inputs(job.video) if job.video is not None else {}


def _settings(job: Job) -> dict:
    from mvm.video.frames import frame_settings

    return frame_settings(job.options.frames)


def _files(job: Job) -> list[Path]:
    from mvm.errors import InputError
    from mvm.video.frames import read_frame_index

    index = job.layout.frames_index
    if not index.is_file():
        return []
    try:
        names = list(read_frame_index(job.scene).names)
    except InputError:
        return [index]
    return [index] + [job.layout.frames / n for n in sorted(names)]


def _run(job: Job, force: bool) -> Done:
    from mvm.video.frames import extract_frames

    index = extract_frames(job.video, job.scene, job.options.frames, force=force, progress=job.tick("frames"))
    return Done(index, index.why)


def _applies(job: Job) -> str | None:
    return "no video: a scene directory" if job.video is None else None


def _record(job: Job) -> Path:
    return job.layout.frames_index


STAGE = Stage("frames", "the frame extraction", ("frames",), _record, _inputs, _settings, _files, _run,
              applies=_applies)
