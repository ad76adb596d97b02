"""Scenes reconstructed together (one refinement solve) give each scene its own numbers."""
from __future__ import annotations

import numpy as np
import pytest

import mvm.core.pipeline as pipeline
from mvm.core.config import Config
from mvm.core.reconstruct import reconstruct, reconstruct_many
from mvm.core.scene import Cameras, Poses2D, Scene
from mvm.errors import InputError
from mvm.sim.rig import detect_views, ring_cameras, walking_people


def one_instant_scenes(count: int, seed: int = 0, views: int = 5) -> tuple[list[Scene], np.ndarray]:
    """``count`` one-instant scenes of 3 people walking in a ring of ``views`` cameras (detector
    noise, dropouts, false poses): the scenes and the true joints ``(count, 3, 17, 3)``."""
    rng = np.random.default_rng(seed)
    cameras = ring_cameras(views)
    truth = walking_people(3, count, rng)
    scenes = []
    for t in range(count):
        kp, cam, _ = detect_views(cameras, truth[t], rng)
        poses = Poses2D(kp, cam, np.arange(len(kp)), np.ones(len(kp)))
        scenes.append(Scene(f"instant_{t}", cameras, poses))
    return scenes, truth


def test_scenes_together_give_what_each_gives_alone():
    """Scenes of 5 and of 7 views (persons padded to different widths, solved apart), and a
    bad scene among them."""
    five, seven = one_instant_scenes(4), one_instant_scenes(3, seed=2, views=7)
    scenes, truth = five[0][:2] + seven[0] + five[0][2:], np.concatenate([five[1][:2], seven[1], five[1][2:]])
    bad = Scene("bad", Cameras(scenes[0].cameras.K, scenes[0].cameras.R, scenes[0].cameras.t * np.nan,
                               scenes[0].cameras.size, scenes[0].cameras.names), scenes[0].poses)
    together = reconstruct_many(scenes[:3] + [bad] + scenes[3:], Config())
    assert isinstance(together[3], InputError) and "bad" in str(together[3])
    del together[3]
    for scene, many, true in zip(scenes, together, truth):
        alone = reconstruct(scene, Config())
        assert [m.tolist() for m in many.persons.members] == [m.tolist() for m in alone.persons.members]
        np.testing.assert_allclose(many.persons.keypoints3d, alone.persons.keypoints3d, rtol=0, atol=1e-9)
        assert many.metrics == pytest.approx(alone.metrics, rel=1e-9, nan_ok=True)
        assert many.warnings == alone.warnings
        assert set(many.timings) == set(alone.timings)
        error = np.linalg.norm(many.persons.keypoints3d[:, None] - true[None], axis=-1)     # (found, true, J)
        assert len(many.persons) == 3 and np.nanmean(error, -1).min(1).max() < 0.05       # metres


def test_a_solve_that_fails_together_is_made_scene_by_scene(monkeypatch):
    """A refinement that fails outright on the stacked persons is solved again part by part:
    every scene still gets its refined poses."""
    scenes, _ = one_instant_scenes(4, seed=1)
    alone = [reconstruct(s, Config()) for s in scenes]
    real, calls = pipeline.refine_poses, []

    def fails_on_many(X, *args, **kwargs):
        calls.append(len(X))
        if len(X) > max(len(a.persons) for a in alone):
            raise np.linalg.LinAlgError("singular")
        return real(X, *args, **kwargs)

    monkeypatch.setattr(pipeline, "refine_poses", fails_on_many)
    together = reconstruct_many(scenes, Config())
    assert calls[0] == sum(len(a.persons) for a in alone) and len(calls) == 1 + len(scenes)
    for many, one in zip(together, alone):
        np.testing.assert_allclose(many.persons.keypoints3d, one.persons.keypoints3d, rtol=0, atol=1e-9)
        assert many.metrics["refine_fallbacks"] == 0
