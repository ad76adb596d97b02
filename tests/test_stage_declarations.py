"""Every scene stage's declaration (:meth:`mvm.stages.Stage.why`, what ``mvm status`` and ``mvm
batch`` ask) agrees with what its run decides (:func:`mvm.io.provenance.produce`, inside the
stage's library function), stage by stage, asked just before the stage runs: on the first run, on
a rerun with nothing changed, after a change of the last stage's setting, and after a change of
the first stage's setting, which makes the stages after it stale through their inputs. A rendered
clip with its true cameras (imported) and its projected true joints (imported): no SfM, no
detector model."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from mvm.core.config import Config
from mvm.io.colmap import write_colmap
from mvm.sim.mannequin_video import RenderConfig, render_video
from mvm.stages import RUN_STAGES, Job, SceneOptions, run_stage
from mvm.video.frames import FrameOptions

from helpers import coco_results


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    root = tmp_path_factory.mktemp("clip")
    truth = render_video(root / "tour.mp4", RenderConfig(frames=8, width=240, height=136, focal_px=200.0, seed=5))
    write_colmap(root / "model", truth.cameras)
    (root / "detections.json").write_text(json.dumps(coco_results(truth, np.random.default_rng(0))))
    return root


def _job(root, scene, config: Config, frames: FrameOptions = FrameOptions(blur_ratio=0.0, select="all")) -> Job:
    options = SceneOptions(config=config, frames=frames)
    return Job(scene, options, root / "tour.mp4", root / "detections.json", cameras=root / "model")


def _declared_and_made(job: Job) -> dict[str, tuple]:
    """``{stage: (its declaration's reason just before it ran, the run's reason)}``."""
    out = {}
    for stage in RUN_STAGES:
        if stage.applies(job) is None:
            declared = stage.why(job)
            out[stage.name] = (declared, run_stage(stage, job).why)
    return out


def test_declarations_and_runs_decide_alike(clip, tmp_path):
    scene = tmp_path / "tour"
    first = _declared_and_made(_job(clip, scene, Config()))
    assert all(pair == ("no output yet", "no output yet") for pair in first.values()), first
    again = _declared_and_made(_job(clip, scene, Config()))
    assert all(pair == (None, None) for pair in again.values()), again

    changed = _declared_and_made(_job(clip, scene, dataclasses.replace(Config(), gamma=2.0)))
    assert all(declared == made for declared, made in changed.values()), changed
    assert [n for n, (why, _) in changed.items() if why] == ["reconstruct"]
    assert "gamma changed" in changed["reconstruct"][0]

    fewer = _declared_and_made(_job(clip, scene, dataclasses.replace(Config(), gamma=2.0),
                                    FrameOptions(blur_ratio=0.0, select="all", max_frames=6)))
    assert all(declared == made for declared, made in fewer.values()), fewer
    assert "max_frames changed" in fewer["frames"][0]
    assert fewer["detect"][0] and fewer["reconstruct"][0], fewer                # stale through their inputs
