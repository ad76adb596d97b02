"""The rig's ``reconstruct``: every instant reconstructed, persons linked over time, completed and
written as one output set (:func:`mvm.rig.reconstruct_rig.reconstruct_rig`): ``poses3d.jsonl``,
``tracks/*.trc``, ``recap.json``, with the set's record inside it (written in the same swap)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mvm.io.layout import RECAP, RIG_POSES3D, TRACKS_DIR
from mvm.stages.stage import Done, RigJob, Stage, present


@dataclass
class RigSet:
    """What the rig's ``reconstruct`` made or kept: the ``recap`` and the ``outputs``' paths
    (``poses3d``, ``tracks``, ``recap``)."""

    recap: dict
    outputs: dict


def _settings_of(job: RigJob):
    from mvm.rig.options import RigOptions
    from mvm.rig.reconstruct_rig import rig_config

    return rig_config(job.config), job.options or RigOptions()


def _out_dir(job: RigJob) -> Path:
    from mvm.rig.output_set import check_rig_output

    return check_rig_output(job.rig_dir, job.calib, job.output)


def _inputs(job: RigJob) -> dict:
    from mvm.rig.reconstruct_rig import rig_fingerprint_inputs

    return rig_fingerprint_inputs(job.rig_dir, job.calib)


def _settings(job: RigJob) -> dict:
    from mvm.rig.reconstruct_rig import rig_settings

    config, options = _settings_of(job)
    return rig_settings(config, options, job.calib, job.frames)


def _files(job: RigJob) -> list[Path]:
    out = _out_dir(job)
    tracks = sorted((out / TRACKS_DIR).glob("*.trc")) if (out / TRACKS_DIR).is_dir() else []
    return present(out / RIG_POSES3D, out / RECAP) + tracks


def _reason(job: RigJob) -> str | None:
    from mvm.rig.reconstruct_rig import rig_reason

    config, options = _settings_of(job)
    return rig_reason(job.rig_dir, config, options, job.calib, job.frames, job.output)


def _run(job: RigJob, force: bool) -> Done:
    from mvm.rig.reconstruct_rig import kept_set, reconstruct_rig

    why = "forced" if force else _reason(job)
    if why is None:
        return Done(RigSet(*kept_set(job.rig_dir, job.calib, job.output)), None)
    config, options = _settings_of(job)
    result = reconstruct_rig(job.rig_dir, config, options, job.calib, job.frames, job.output,
                             progress=job.tick("instants"))
    return Done(RigSet(result.recap, result.outputs), why)


STAGE = Stage("reconstruct", "the rig reconstruction", ("reconstruct", "rig"),
              lambda job: _out_dir(job) / RIG_POSES3D, _inputs, _settings, _files, _run, reason=_reason)
