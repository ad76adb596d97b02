"""``export``: the 3D poses projected into every frame of the clip, a COCO data set with
relative depths (:func:`mvm.net.supervision.export_supervision`): ``<output>/supervision/``,
its frames left where they are (its file names relative to it: the scene can move);
``mvm batch`` merges the clips' data sets into one."""
from __future__ import annotations

from pathlib import Path

from mvm.io.layout import SUPERVISION_DIR, SUPERVISION_FILE
from mvm.stages.stage import Done, Job, Stage, present


def _folder(job: Job) -> Path:
    return job.layout.supervision


def _annotations(job: Job) -> Path:
    return _folder(job) / SUPERVISION_FILE


def _inputs(job: Job) -> dict:
    from mvm.net.supervision import export_inputs

    return export_inputs([job.scene], job.options.output)


def _settings(job: Job) -> dict:
    from mvm.net.supervision import export_settings

    return export_settings("none", job.options.min_keypoints, False, f"{job.options.output}/{SUPERVISION_DIR}")


def _run(job: Job, force: bool) -> Done:
    from mvm.errors import InputError
    from mvm.io.provenance import produce
    from mvm.io.scene_dir import check_reconstruction_fresh, read_poses3d, read_scene
    from mvm.net.supervision import EXPORT_STAGE, export_supervision

    scene = job.scene
    poses3d = job.layout.poses3d
    if not poses3d.is_file():
        raise InputError(poses3d, None, "not found: the clip is not reconstructed")

    def make(why: str, hashed: dict) -> Path:
        check_reconstruction_fresh(scene, poses3d)
        frames = job.layout.frames
        item = (read_scene(scene), read_poses3d(poses3d, root=scene), frames if frames.is_dir() else None)
        return export_supervision([item], _folder(job), link="none", min_keypoints=job.options.min_keypoints)

    path, why = produce(_annotations(job), EXPORT_STAGE, _inputs(job), _settings(job), make, lambda: _annotations(job),
                        force=force)                                  # the writer locks its folder
    return Done(path, why)


STAGE = Stage("export", "the export", (), _annotations, _inputs, _settings, lambda job: present(_annotations(job)),
              _run)
