"""``reconstruct``: the 3D poses of the scene (:func:`mvm.scenes.reconstruct_read`), its world
scaled to metres from the people's bone lengths (:func:`mvm.video.metric_scale.apply_metric_scale`)
before ``poses3d.json`` is written, once, under the output folder's lock."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mvm.io.layout import SPARSE
from mvm.stages.stage import Done, Job, Stage, present


@dataclass
class Reconstruction:
    """What ``reconstruct`` made or kept: the number of ``persons``, the scene's ``metrics``,
    the ``scale`` record (:class:`mvm.video.metric_scale.ScaleRecord`) and the file's ``path``."""

    persons: int
    metrics: dict
    scale: object
    path: Path


def _poses3d(job: Job) -> Path:
    return job.layout.poses3d


def _config(job: Job):
    from mvm.core.reconstruct import scene_config

    return scene_config(job.options.config)


def _inputs(job: Job) -> dict:
    from mvm.io.scene_dir import reconstruction_inputs

    return reconstruction_inputs(job.scene)


def _metric_scale(job: Job) -> bool:
    """Whether the world is scaled to metres: asked for, and the cameras are the clip's own
    (made from its video); a scene directory's cameras are its owner's, and stay as they are."""
    return job.options.metric_scale and job.video is not None


def _settings(job: Job) -> dict:
    from mvm.io.scene_dir import reconstruct_settings

    return reconstruct_settings(_config(job), _metric_scale(job))


def _files(job: Job) -> list[Path]:
    """``poses3d.json`` and the camera model as scaled with it (``sparse/``, ``sfm/scale.json``)."""
    sparse = job.layout.sparse
    model = sorted(p for p in sparse.rglob("*") if p.is_file()) if sparse.is_dir() else []
    return present(_poses3d(job)) + model + present(job.layout.scale_file) if present(_poses3d(job)) \
        else []


def _kept(job: Job) -> Reconstruction:
    from mvm.io.scene_dir import load_poses3d_document
    from mvm.video.metric_scale import ScaleRecord

    doc = load_poses3d_document(_poses3d(job), root=job.scene)
    scale = (ScaleRecord(**doc["scale"]) if isinstance(doc.get("scale"), dict)
             else ScaleRecord("none", None, None, False))
    return Reconstruction(len(doc.get("persons", [])), doc.get("metrics", {}), scale, _poses3d(job))


def _run(job: Job, force: bool) -> Done:
    from mvm.io.provenance import fingerprint, produce
    from mvm.io.scene_dir import RECONSTRUCT_STAGE, output_dir
    from mvm.scenes import reconstruct_read, result_document, write_result
    from mvm.video.metric_scale import apply_metric_scale

    config = _config(job)
    out_dir = output_dir(job.scene, job.options.output)

    def make(why: str, hashed: dict) -> Reconstruction:
        result, scene = reconstruct_read(job.scene, config, job.options.output)
        scale = apply_metric_scale(job.scene, result.persons, _metric_scale(job))
        if scale.applied_to_model:
            hashed[SPARSE] = fingerprint(job.layout.sparse)          # the model as scaled
        write_result(out_dir, result_document(result, scene, config, {"scale": scale.to_json()}), result.timings)
        return Reconstruction(len(result.persons), result.metrics, scale, _poses3d(job))

    made, why = produce(_poses3d(job), RECONSTRUCT_STAGE, _inputs(job), _settings(job), make, lambda: _kept(job),
                        force=force, lock=_poses3d(job), lock_timeout_s=config.lock_timeout_s)
    return Done(made, why)


STAGE = Stage("reconstruct", "the reconstruction", ("reconstruct",), _poses3d, _inputs, _settings, _files, _run)
