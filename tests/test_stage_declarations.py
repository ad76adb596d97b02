"""Every scene stage's declaration (:meth:`mvm.stages.Stage.why`, what ``mvm status`` and ``mvm
batch`` ask) agrees with what its run decides (:func:`mvm.io.provenance.produce`, inside the
stage's library function): after a run every stage is up to date by both; after a change of one
stage's setting, that stage and the ones after it are stale by both, for the same reason. A
rendered clip with its true cameras (imported) and its projected true joints (imported): no SfM,
no detector model."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from mvm.core.config import Config
from mvm.io.colmap import write_colmap
from mvm.sim.mannequin_video import RenderConfig, render_video
from mvm.stages import RUN_STAGES, Job, SceneOptions, run_stages
from mvm.video.frames import FrameOptions

from helpers import coco_results


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    root = tmp_path_factory.mktemp("clip")
    truth = render_video(root / "tour.mp4", RenderConfig(frames=8, width=240, height=136, focal_px=200.0, seed=5))
    write_colmap(root / "model", truth.cameras)
    (root / "detections.json").write_text(json.dumps(coco_results(truth, np.random.default_rng(0))))
    return root


def _job(root, scene, config: Config) -> Job:
    options = SceneOptions(config=config, frames=FrameOptions(blur_ratio=0.0, select="all"))
    return Job(scene, options, root / "tour.mp4", root / "detections.json", cameras=root / "model")


def test_declarations_and_runs_decide_alike(clip, tmp_path):
    scene = tmp_path / "tour"
    first = run_stages(_job(clip, scene, Config()), RUN_STAGES)
    assert all(done.why == "no output yet" for done in first.values()), {n: d.why for n, d in first.items()}
    job = _job(clip, scene, Config())
    assert {stage.name: stage.why(job) for stage in RUN_STAGES} == {stage.name: None for stage in RUN_STAGES}
    assert all(done.why is None for done in run_stages(job, RUN_STAGES).values())

    changed = _job(clip, scene, dataclasses.replace(Config(), gamma=2.0))
    declared = {stage.name: stage.why(changed) for stage in RUN_STAGES}
    assert [n for n, why in declared.items() if why] == ["reconstruct"], declared
    assert "gamma changed" in declared["reconstruct"]
    ran = run_stages(changed, RUN_STAGES)
    assert {name: done.why for name, done in ran.items()} == declared
    assert all(stage.why(changed) is None for stage in RUN_STAGES)
