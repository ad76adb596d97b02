"""The rig's ``detect``: the 2D poses of every video of ``RIG_DIR/videos`` into
``RIG_DIR/pose/<camera>.json``, each with its own record (:func:`mvm.video.rig_videos.detect_rig_videos`:
every camera's decided before any is detected, as the videos' lengths are compared). The stage's
``record`` is the pose folder, its ``inputs`` every video; its ``reason`` names the first camera
whose pose file is out of date."""
from __future__ import annotations

from pathlib import Path

from mvm.io.layout import VIDEOS
from mvm.stages.stage import Done, RigJob, Stage


def _options(job: RigJob):
    from mvm.video.detect import DetectOptions

    return job.detect or DetectOptions(detector="rtmo")


def _pose_files(job: RigJob) -> list[Path]:
    from mvm.video.rig_videos import rig_videos

    folder = job.layout.pose_dir
    return [folder / f"{camera}.json" for camera in sorted(rig_videos(job.rig_dir))
            if (folder / f"{camera}.json").is_file()]


def _inputs(job: RigJob) -> dict:
    from mvm.video.rig_videos import rig_videos

    inputs: dict = {f"{VIDEOS}/{video.name}": video for video in rig_videos(job.rig_dir).values()}
    if job.checkpoint is not None:
        inputs["checkpoint"] = Path(job.checkpoint)
    return inputs


def _settings(job: RigJob) -> dict:
    from dataclasses import replace

    from mvm.video.detect import detect_settings

    options = _options(job)
    return detect_settings(options.detector, None, replace(options, appearance="none"))


def _reason(job: RigJob) -> str | None:
    from mvm.video.rig_videos import rig_detect_reason

    return rig_detect_reason(job.rig_dir, job.checkpoint, _options(job))


def _run(job: RigJob, force: bool) -> Done:
    from mvm.video.rig_videos import detect_rig_videos

    found = detect_rig_videos(job.rig_dir, job.checkpoint, _options(job), force, job.progress)
    return Done(found, next((f"camera {c.camera}: {c.why}" for c in found if c.why is not None), None))


STAGE = Stage("detect", "the rig detection", ("detect",), lambda job: job.layout.pose_dir, _inputs, _settings,
              _pose_files, _run, reason=_reason)
