"""The rig's ``synchronize``: each camera's frame offset from the people's motion, written to
``RIG_DIR/sync.toml`` (:func:`mvm.rig.prepare.synchronize_rig`), its record beside it
(``RIG_DIR/sync.inputs.json``: a record, never a camera's pose file, :func:`mvm.rig.rigdir.pose_sources`).
Its inputs are the calibration, every pose source and the pose folder (not ``sync.toml``
itself); its settings the calibration named and ``max_offset``."""
from __future__ import annotations

from pathlib import Path

from mvm.io.layout import POSE_DIR, SYNC
from mvm.stages.stage import Done, RigJob, Stage, present

#: The stage in the reasons of a rerun.
TITLE = "the synchronization"


def _sync_file(job: RigJob) -> Path:
    return job.layout.sync


def _inputs(job: RigJob) -> dict:
    from mvm.rig.reconstruct_rig import rig_fingerprint_inputs

    inputs = rig_fingerprint_inputs(job.rig_dir, job.calib)
    folder = {POSE_DIR: inputs.pop(POSE_DIR)} if POSE_DIR in inputs else {}  # last: a reason names the camera's file
    return {name: path for name, path in inputs.items() if name != SYNC} | folder


def _settings(job: RigJob) -> dict:
    return {"calib": str(job.calib) if job.calib else None, "max_offset": job.max_offset}


def _run(job: RigJob, force: bool) -> Done:
    """``Done.result``: the :class:`~mvm.rig.prepare.RigSync` found, or, kept, the offsets of
    ``sync.toml`` (``{camera: frames}``)."""
    from mvm.io.provenance import produce
    from mvm.io.sync_toml import read_sync_toml
    from mvm.rig.prepare import synchronize_rig

    path, rig_dir = _sync_file(job), Path(job.rig_dir)
    result, why = produce(path, TITLE, _inputs(job), _settings(job),
                          lambda why, hashed: synchronize_rig(rig_dir, job.calib, job.max_offset),
                          lambda: read_sync_toml(path), force=force, lock=path if rig_dir.is_dir() else None)
    return Done(result, why)


STAGE = Stage("synchronize", TITLE, (), _sync_file, _inputs, _settings, lambda job: present(_sync_file(job)), _run)
