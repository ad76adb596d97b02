"""The runner of :mod:`mvm.stages` with a stage written here, as a contributor adds one: a CSV
export of the 3D joints, one ``Stage`` declaration whose ``run`` goes through
:func:`mvm.io.provenance.produce`. Made when missing, kept when its inputs and settings are
unchanged, made again when a setting changes or an earlier stage is forced."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mvm.io.files import atomic_write_bytes
from mvm.io.ground_truth import write_simulation
from mvm.io.provenance import produce, read_record
from mvm.sim.simulate import SimConfig, simulate
from mvm.stages import Done, Job, SceneOptions, Stage, run_stages, scene_stage


def _csv(job: Job) -> Path:
    return job.scene / job.options.output / "joints.csv"


def _inputs(job: Job) -> dict:
    return {"poses3d.json": job.scene / job.options.output / "poses3d.json"}


DIGITS = {"digits": 3}


def _run(job: Job, force: bool) -> Done:
    def make(why, hashed):
        persons = json.loads(_inputs(job)["poses3d.json"].read_text())["persons"]
        rows = [f"{p['id']},{j}," + ",".join("" if v is None else f"{v:.{DIGITS['digits']}f}" for v in kp[:3])
                for p in persons for j, kp in enumerate(p["keypoints3d"])]
        atomic_write_bytes(_csv(job), ("person,joint,x,y,z\n" + "\n".join(rows) + "\n").encode())
        return _csv(job)

    path, why = produce(_csv(job), "the csv export", _inputs(job), dict(DIGITS), make, lambda: _csv(job),
                        force=force, lock=job.scene / job.options.output)
    return Done(path, why)


CSV = Stage("csv", "the csv export", (), _csv, _inputs, lambda job: dict(DIGITS),
            lambda job: [_csv(job)] if _csv(job).is_file() else [], _run)


def test_a_new_stage_is_made_kept_and_redone_by_the_runner(tmp_path, monkeypatch):
    scene, truth = simulate(SimConfig(people=2, frames=10, seed=5))
    write_simulation(tmp_path / "scene", scene, truth)
    job = Job(tmp_path / "scene", SceneOptions(metric_scale=False))
    stages = [scene_stage("reconstruct"), CSV]

    done = run_stages(job, stages)
    assert done["reconstruct"].why == done["csv"].why == "no output yet"
    document = json.loads((job.scene / "mvm" / "poses3d.json").read_text())
    table = np.genfromtxt(_csv(job), delimiter=",", skip_header=1)
    assert len(table) == 17 * len(document["persons"]) == 17 * len(truth.poses3d)
    joints = np.array([[np.nan if v is None else v for v in kp[:3]] for p in document["persons"]
                       for kp in p["keypoints3d"]])
    assert np.allclose(table[:, 2:], joints, atol=5e-4, equal_nan=True)       # 3 digits
    assert read_record(_csv(job))["settings"] == {"digits": 3}

    before = _csv(job).stat().st_mtime_ns
    again = run_stages(job, stages)
    assert again["reconstruct"].why is None and again["csv"].why is None
    assert _csv(job).stat().st_mtime_ns == before

    monkeypatch.setitem(DIGITS, "digits", 4)
    changed = run_stages(job, stages)
    assert changed["reconstruct"].why is None
    assert changed["csv"].why == "setting digits changed since the csv export (3 -> 4)"

    forced = run_stages(job, stages, force=("reconstruct",))      # a forced stage forces the ones after it
    assert forced["reconstruct"].why == forced["csv"].why == "forced"


def test_each_stage_s_title_is_the_one_its_records_are_written_with():
    """``mvm status`` words a reason with the stage's declared title, the run with the library's
    constant; the declarations import no library (``mvm --help`` stays light), so this test holds
    the two alike."""
    from mvm.io.scene_dir import RECONSTRUCT_STAGE
    from mvm.net.supervision import EXPORT_STAGE
    from mvm.rig.reconstruct_rig import RIG_STAGE
    from mvm.stages import RIG_STAGES, SCENE_STAGES
    from mvm.video.detect import DETECT_STAGE
    from mvm.video.frames import FRAMES_STAGE
    from mvm.video.rig_videos import RIG_DETECT_STAGE
    from mvm.video.sfm import SFM_STAGE

    scene = {stage.name: stage.title for stage in SCENE_STAGES}
    rig = {stage.name: stage.title for stage in RIG_STAGES}
    assert scene == {"frames": FRAMES_STAGE, "sfm": SFM_STAGE, "detect": DETECT_STAGE,
                     "reconstruct": RECONSTRUCT_STAGE, "export": EXPORT_STAGE}
    assert rig["detect"] == RIG_DETECT_STAGE and rig["reconstruct"] == RIG_STAGE
