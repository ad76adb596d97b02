"""Degenerate geometry and numerical hygiene: each case ends in a clear outcome (a result
checked against the ground truth it was built from, or a warning saying why nothing could be
reconstructed, or a one-line refusal), never a crash, a NaN in an output or a partial file."""
from __future__ import annotations

import json
import math
import tracemalloc

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.main import main
from mvm.core.affinity import affinity_bytes, epipolar_distance
from mvm.core.config import Config
from mvm.core.reconstruct import reconstruct
from mvm.core.scene import Cameras, Poses2D, Scene
from mvm.errors import InputError
from mvm.io.files import atomic_write_json
from mvm.io.scene_dir import write_scene
from mvm.scenes import reconstruct_dir
from mvm.sim.simulate import SimConfig, look_at, simulate

from helpers import standing_poses


def people(n: int, spacing: float = 1.5) -> np.ndarray:
    """``(n, 17, 3)`` standing people on a line along x, centred on the origin, facing -y."""
    poses = standing_poses(n, seed=1, jitter=0.01).copy()
    poses[..., 1] *= -1
    poses[..., 0] += (np.arange(n) - (n - 1) / 2)[:, None] * spacing
    return poses


def cameras_at(centers: np.ndarray, targets: np.ndarray, focal: float = 1000.0) -> Cameras:
    V = len(centers)
    R = look_at(centers, targets)
    t = -np.einsum("vij,vj->vi", R, centers)
    K = np.array([[focal, 0, 640], [0, focal, 360], [0, 0, 1.0]])
    return Cameras(np.broadcast_to(K, (V, 3, 3)).copy(), R, t, np.broadcast_to([1280.0, 720.0], (V, 2)).copy(),
                   tuple(f"f{v:03d}.jpg" for v in range(V)))


def observe(cameras: Cameras, poses3d: np.ndarray, noise_px: float = 0.5, seed: int = 0) -> Poses2D:
    """Project every person into every camera it is in front of; keypoints outside the image or
    behind the camera are missing (confidence 0)."""
    rng = np.random.default_rng(seed)
    kp, view = [], []
    for v in range(len(cameras)):
        x = np.einsum("ab,pjb->pja", cameras.R[v], poses3d) + cameras.t[v]
        depth = x[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.einsum("ab,pjb->pja", cameras.K[v], x)[..., :2] / depth[..., None]
        uv = uv + rng.normal(0, noise_px, uv.shape)
        seen = (depth > 0) & (uv >= 0).all(-1) & (uv < cameras.size[v]).all(-1)
        for p in np.flatnonzero(seen.sum(1) >= 5):
            kp.append(np.concatenate([np.where(seen[p, :, None], uv[p], 0.0), seen[p, :, None] * 0.9], 1))
            view.append(v)
    n = len(kp)
    return Poses2D(np.array(kp).reshape(n, 17, 3), np.array(view, dtype=int), np.arange(n), np.full(n, 0.9))


def arc(V: int, radius: float = 5.0, arc_deg: float = 90.0) -> np.ndarray:
    angles = np.radians(np.linspace(-arc_deg / 2, arc_deg / 2, V)) - np.pi / 2
    return np.stack([radius * np.cos(angles), radius * np.sin(angles), np.full(V, 1.5)], 1)


def assert_clean(result) -> None:
    """No infinity anywhere, a joint is whole or null, the document serializes without NaN."""
    from mvm.io.scene_dir import poses3d_document

    X = result.persons.keypoints3d
    assert not np.isinf(X).any()
    assert (np.isnan(X).all(-1) | np.isfinite(X).all(-1)).all()
    json.dumps(poses3d_document(result.persons, result.scene.poses, result.metrics, {"w": result.warnings}),
               allow_nan=False)


def mpjpe(result, truth: np.ndarray) -> float:
    X = result.persons.keypoints3d
    errors = [np.nanmean(np.linalg.norm(X[p] - truth, axis=-1), axis=-1).min() for p in range(len(X))]
    return float(np.max(errors))


# --- geometry -------------------------------------------------------------------------------


def test_reference_arc_scene_is_reconstructed():
    truth = people(3)
    cams = cameras_at(arc(12), np.broadcast_to([0, 0, 1.0], (12, 3)))
    result = reconstruct(Scene("arc", cams, observe(cams, truth)), Config())
    assert len(result.persons) == 3 and not result.warnings
    assert mpjpe(result, truth) < 0.02
    assert_clean(result)


def test_all_frames_from_one_place_leave_joints_null_and_say_why():
    truth = people(3)
    centers = np.broadcast_to([0.0, -5.0, 1.5], (10, 3))
    targets = np.stack([np.linspace(-1.5, 1.5, 10), np.zeros(10), np.ones(10)], 1)   # panning, no parallax
    cams = cameras_at(centers, targets)
    result = reconstruct(Scene("pan", cams, observe(cams, truth)), Config())
    assert len(result.persons) == 0
    assert any("no parallax" in w for w in result.warnings), result.warnings
    assert_clean(result)


def test_tiny_baseline_leaves_joints_null_for_low_parallax():
    truth = people(2)
    centers = np.array([0.0, -5.0, 1.5]) + np.linspace(-0.005, 0.005, 8)[:, None] * [1, 0, 0]   # 1 cm
    cams = cameras_at(centers, np.broadcast_to([0, 0, 1.0], (8, 3)))
    result = reconstruct(Scene("tiny", cams, observe(cams, truth, noise_px=0.0)), Config(min_group_size=2))
    assert len(result.persons) == 0
    assert any("min_parallax_deg" in w for w in result.warnings), result.warnings
    assert_clean(result)


def test_two_frames_say_why_by_default_and_work_when_allowed():
    truth = people(2)
    cams = cameras_at(arc(2, arc_deg=40), np.broadcast_to([0, 0, 1.0], (2, 3)))
    scene = Scene("two", cams, observe(cams, truth))
    default = reconstruct(scene, Config())
    assert len(default.persons) == 0
    assert any("2 view(s) only" in w and "min_group_size" in w for w in default.warnings)
    allowed = reconstruct(scene, Config(min_group_size=2, ransac=False, refine=False))
    assert len(allowed.persons) == 2
    assert mpjpe(allowed, truth) < 0.03
    assert_clean(allowed)


def test_a_person_seen_once_stays_unmatched():
    truth = people(3)
    cams = cameras_at(arc(10), np.broadcast_to([0, 0, 1.0], (10, 3)))
    poses = observe(cams, truth)
    loner = people(1)
    loner[..., 0] += 6.0                                      # far to the side
    extra = observe(cams.subset(np.array([0])), loner + [[0, 0, 0]])
    if len(extra) == 0:                                       # put them where camera 0 looks
        lone_cam = cams.subset(np.array([0]))
        loner = people(1) + (cams.centers[0] * 0.3)[None, None]
        extra = observe(lone_cam, loner)
    assert len(extra) == 1
    merged = Poses2D(np.concatenate([poses.keypoints, extra.keypoints]), np.concatenate([poses.view, [0]]),
                     np.arange(len(poses) + 1), np.full(len(poses) + 1, 0.9))
    result = reconstruct(Scene("loner", cams, merged), Config())
    assert len(result.persons) == 3
    assert all(len(poses) not in m for m in result.persons.members)
    assert result.metrics["unmatched_poses"] >= 1
    assert mpjpe(result, truth) < 0.02


def test_collinear_cameras():
    truth = people(3, spacing=1.2)
    V = 12
    centers = np.stack([np.linspace(-3, 3, V), np.full(V, -6.0), np.full(V, 1.5)], 1)   # one straight line
    cams = cameras_at(centers, centers + [0, 6.0, -0.5])                               # all parallel
    result = reconstruct(Scene("line", cams, observe(cams, truth)), Config())
    assert len(result.persons) == 3
    assert mpjpe(result, truth) < 0.03
    assert_clean(result)


def test_cameras_facing_away_give_no_persons_and_no_nan():
    truth = people(2)
    cams = cameras_at(arc(8), np.broadcast_to([0, 0, 1.0], (8, 3)))
    poses = observe(cams, truth)
    flip = np.diag([-1.0, 1.0, -1.0])                         # 180° about each camera's y axis
    away = Cameras(cams.K, flip @ cams.R, cams.t @ flip.T, cams.size, cams.names)
    np.testing.assert_allclose(away.centers, cams.centers, atol=1e-9)
    result = reconstruct(Scene("away", away, poses), Config())
    # The people are behind every camera: nothing may be placed where they are. (Reversed rays
    # of two neighbouring views can still meet in front of both, far away: that is a valid
    # reading of the input, and most joints are reported unreconstructed.)
    assert any("unreconstructed" in w for w in result.warnings), result.warnings
    X = result.persons.keypoints3d
    if len(X):
        near_truth = np.linalg.norm(X[:, :, None] - truth.reshape(1, 1, -1, 3), axis=-1).min(-1)
        assert np.nanmin(near_truth) > 1.0
        x_cam = np.einsum("vab,pjb->pjva", away.R, X) + away.t[None, None]
        members = result.persons.members
        for p in range(len(X)):
            depth = x_cam[p][:, poses.view[members[p]], 2]
            assert (depth[np.isfinite(X[p]).all(-1)] > 0).any(axis=-1).all()
    assert_clean(result)


def test_no_detections_in_memory_and_on_disk(tmp_path):
    cams = cameras_at(arc(4), np.broadcast_to([0, 0, 1.0], (4, 3)))
    empty = Poses2D(np.zeros((0, 17, 3)), np.zeros(0, int), np.zeros(0, int), np.zeros(0))
    result = reconstruct(Scene("empty", cams, empty), Config())
    assert len(result.persons) == 0 and result.warnings == ["no 2D poses: nothing to reconstruct"]
    write_scene(tmp_path / "s", cams, empty)
    run = CliRunner().invoke(main, ["reconstruct", str(tmp_path / "s")])
    assert run.exit_code == 2
    errors = [line for line in run.output.splitlines() if line.startswith("mvm: error:")]
    assert len(errors) == 1 and "poses2d.json" in errors[0] and "nothing to reconstruct" in errors[0]
    assert not (tmp_path / "s" / "mvm" / "poses3d.json").exists()


def _crowd_with_one_huge_frame(n_extra: int, seed: int = 0):
    scene, truth = simulate(SimConfig(people=3, frames=20, seed=seed), bank_poses=standing_poses())
    p = scene.poses
    rng = np.random.default_rng(seed)
    kp = np.concatenate([rng.uniform(0, 1280, (n_extra, 17, 1)), rng.uniform(0, 720, (n_extra, 17, 1)),
                         rng.uniform(0.3, 1, (n_extra, 17, 1))], 2)
    app = rng.random((n_extra, p.appearance.shape[1]))
    poses = Poses2D(np.concatenate([p.keypoints, kp]), np.concatenate([p.view, np.zeros(n_extra, int)]),
                    np.concatenate([p.ids, p.ids.max() + 1 + np.arange(n_extra)]),
                    np.concatenate([p.score, rng.uniform(0.2, 1, n_extra)]),
                    np.concatenate([p.appearance, app]))
    return Scene("huge-frame", scene.cameras, poses), truth


def test_ten_thousand_detections_in_one_frame_bounded_memory():
    """10,000 extra detections in frame 0: pairs within a frame are never computed, the affinity
    takes the documented 8 N² bytes (N² float32 for D/A, N² for S), and the crowd is found."""
    scene, truth = _crowd_with_one_huge_frame(10_000)
    N = len(scene.poses)
    tracemalloc.start()
    try:
        result = reconstruct(scene, Config(refine=False))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < affinity_bytes(N, appearance=True) + 200 * 2**20, peak / 2**20
    assert result.metrics["persons"] == 3
    assert mpjpe(result, truth.poses3d) < 0.03
    assert result.metrics["unmatched_poses"] >= 10_000


def test_block_wise_distances_equal_one_block():
    scene, _ = simulate(SimConfig(people=3, frames=15, seed=4), bank_poses=standing_poses())
    p = scene.poses
    whole = epipolar_distance(scene.cameras, p.keypoints, p.view, 0.2, 0.01, 3)
    small = epipolar_distance(scene.cameras, p.keypoints, p.view, 0.2, 0.01, 3, block_bytes=3000)
    np.testing.assert_allclose(whole, small, rtol=1e-5, equal_nan=True)   # float32 sums in another order
    assert np.isinf(whole[p.view[:, None] == p.view[None]]).all()
    assert np.array_equal(whole, whole.T, equal_nan=True)


# --- resources ------------------------------------------------------------------------------


def test_scene_over_the_memory_limit_is_refused_before_work(tmp_path):
    scene, _ = simulate(SimConfig(people=3, frames=20, seed=0), bank_poses=standing_poses())
    N = len(scene.poses)
    limit = affinity_bytes(N, appearance=True) - 1
    with pytest.raises(InputError, match=f"{N} 2D poses need .* MiB .* max_affinity_bytes"):
        reconstruct(scene, Config(max_affinity_bytes=limit))
    reconstruct(scene, Config(max_affinity_bytes=limit + 1, refine=False))           # just fits

    write_scene(tmp_path / "s", scene.cameras, scene.poses)
    run = CliRunner().invoke(main, ["reconstruct", str(tmp_path / "s"), "--set", f"max_affinity_bytes={limit}"])
    assert run.exit_code == 2
    errors = [line for line in run.output.splitlines() if line.startswith("mvm: error:")]
    assert len(errors) == 1, run.output
    assert "poses2d.json: annotations:" in errors[0] and "split the scene" in errors[0]
    assert not (tmp_path / "s" / "mvm").exists()


def test_affinity_memory_grows_as_documented():
    assert affinity_bytes(10_000, appearance=False) - affinity_bytes(0, appearance=False) == 4 * 10_000**2
    assert affinity_bytes(10_000, appearance=True) - affinity_bytes(0, appearance=True) == 8 * 10_000**2


# --- numerical hygiene ----------------------------------------------------------------------


class _WrongPrior:
    """The shipped prior with its means turned 90° about the body's up axis and a tight
    covariance: a heavy weight drags every person into a shape the views contradict."""

    def __init__(self, prior):
        self.prior = prior

    def best_component(self, canonical):
        return self.prior.best_component(canonical)

    def whitening(self, present, component):
        mean, W, c = self.prior.whitening(present, component)
        m = mean.reshape(-1, 3)[:, [1, 0, 2]] * [1, -1, 1] * 3.0
        return m.reshape(-1), W * 100.0, c

    def __getattr__(self, name):
        return getattr(self.prior, name)


def test_diverging_refinement_falls_back_and_says_so():
    from mvm.core.prior import shipped_prior

    scene, truth = simulate(SimConfig(people=3, frames=20, seed=2), bank_poses=standing_poses())
    plain = reconstruct(scene, Config(refine=False))
    bad = reconstruct(scene, Config(prior_weight=1e6), prior=_WrongPrior(shipped_prior()))
    assert bad.metrics["refine_fallbacks"] >= 1
    assert any("refinement diverged" in w for w in bad.warnings)
    kept = [p for p in range(len(bad.persons))
            if np.allclose(bad.persons.keypoints3d[p], plain.persons.keypoints3d[p], equal_nan=True)]
    assert len(kept) >= bad.metrics["refine_fallbacks"]
    assert_clean(bad)


def test_refinement_that_raises_falls_back(monkeypatch):
    import sys

    rec = sys.modules["mvm.core.pipeline"]

    def broken(*args, **kwargs):
        raise ValueError("Residuals are not finite in the initial point.")

    scene, _ = simulate(SimConfig(people=2, frames=10, seed=3), bank_poses=standing_poses())
    plain = reconstruct(scene, Config(refine=False))
    monkeypatch.setattr(rec, "refine_poses", broken)
    result = reconstruct(scene, Config())
    assert result.metrics["refine_fallbacks"] == len(result.persons) > 0
    np.testing.assert_array_equal(result.persons.keypoints3d, plain.persons.keypoints3d)


def test_writer_refuses_nan_and_writes_nothing(tmp_path):
    path = tmp_path / "out.json"
    with pytest.raises(ValueError, match=r"persons\[0\]\.keypoints3d\[1\]\[2\]: refusing to write a non-finite"):
        atomic_write_json(path, {"persons": [{"keypoints3d": [[0.0, 1.0, 2.0], [1.0, 2.0, math.inf]]}]})
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match=r"json: x: refusing to write a non-finite"):
        atomic_write_json(path, {1: np.float64(1.5), "x": np.float64(np.nan)}, pretty=True)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("pretty", [False, True])
def test_writer_reads_back_what_it_was_given(tmp_path, pretty):
    """Both formatters (orjson, and the standard library for what orjson refuses: numpy
    floats, keys that are not strings) write JSON that reads back to the same values."""
    plain = {"a": [1, 2.5, -1.234567891e-7, None, True], "b": {"c": "é", "d": []}, "e": 1e300}
    path = tmp_path / "plain.json"
    atomic_write_json(path, plain, pretty=pretty)
    assert json.loads(path.read_text(encoding="utf-8")) == plain
    assert ("\n  " in path.read_text(encoding="utf-8")) == pretty
    atomic_write_json(path, {1: np.float64(0.1), "n": [np.float64(-2.0)]}, pretty=pretty)
    assert json.loads(path.read_text()) == {"1": 0.1, "n": [-2.0]}


@pytest.mark.parametrize("field,change", [
    ("cameras[1].t", lambda c, p: (Cameras(c.K, c.R, np.where(np.arange(len(c))[:, None] == 1, np.nan, c.t),
                                           c.size, c.names), p)),
    ("cameras[0].K", lambda c, p: (Cameras(c.K * np.where(np.arange(len(c)) == 0, 0.0, 1.0)[:, None, None],
                                           c.R, c.t, c.size, c.names), p)),
    ("cameras[0].R", lambda c, p: (Cameras(c.K, c.R * np.where(np.arange(len(c)) == 0, 2.0, 1.0)[:, None, None],
                                           c.t, c.size, c.names), p)),
    ("annotations[id=", lambda c, p: (c, Poses2D(np.where(np.arange(len(p))[:, None, None] == 2, np.inf, p.keypoints),
                                                 p.view, p.ids, p.score, p.appearance))),
])
def test_unusable_numbers_are_refused_in_one_line(field, change):
    scene, _ = simulate(SimConfig(people=2, frames=6, seed=0), bank_poses=standing_poses())
    cams, poses = change(scene.cameras, scene.poses)
    with pytest.raises(InputError) as error:
        reconstruct(Scene("bad", cams, poses), Config())
    assert str(error.value).startswith(f"bad: {field}") and "\n" not in str(error.value)


def test_written_output_has_no_nan_and_carries_the_warnings(tmp_path):
    truth = people(2)
    cams = cameras_at(arc(2, arc_deg=40), np.broadcast_to([0, 0, 1.0], (2, 3)))
    write_scene(tmp_path / "s", cams, observe(cams, truth))
    reconstruct_dir(tmp_path / "s", Config())
    text = (tmp_path / "s" / "mvm" / "poses3d.json").read_text()
    document = json.loads(text)
    assert "NaN" not in text and "Infinity" not in text
    assert document["persons"] == [] and any("2 view(s) only" in w for w in document["warnings"])
    assert document["metrics"]["E_R_px"] is None
