"""Property-based fuzzing of reconstruction on mutated simulated scenes.

Contract: ``reconstruct`` (in memory) and ``mvm reconstruct`` (on disk) either return a valid
result or refuse with an ``InputError`` (one line, exit status 2); a result holds finite
numbers or NaN (written as null), never infinity; a refused scene leaves no output file.

The strategies here are shared with ``benchmarks/fuzz_reconstruct.py``, which runs 10,000+
cases; the suite runs a few dozen.
"""
from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mvm.core.config import Config
from mvm.core.reconstruct import reconstruct
from mvm.core.scene import Cameras, Poses2D, Scene
from mvm.errors import InputError

try:
    from helpers import standing_poses
except ImportError:                                        # imported from benchmarks/
    from tests.conftest import standing_poses


@functools.cache
def base_scenes() -> tuple[Scene, ...]:
    """Small valid simulated scenes (1 to 3 people, 6 to 12 frames) that mutations start from."""
    from mvm.sim.simulate import SimConfig, simulate

    specs = [(1, 6, 0), (2, 8, 1), (3, 12, 2), (2, 10, 3)]
    return tuple(simulate(SimConfig(people=p, frames=f, seed=s), bank_poses=standing_poses())[0]
                 for p, f, s in specs)


def _rotate_away(cameras: Cameras, index: np.ndarray) -> Cameras:
    """Turn the cameras ``index`` by 180° about their own y axis (same centre, facing away)."""
    flip = np.diag([-1.0, 1.0, -1.0])
    R, t = cameras.R.copy(), cameras.t.copy()
    R[index] = flip @ R[index]
    t[index] = t[index] @ flip.T
    return Cameras(cameras.K, R, t, cameras.size, cameras.names)


def apply_mutation(scene: Scene, op: tuple, rng: np.random.Generator) -> Scene:
    """One mutation of ``scene``: ``op = (name, value)``; ``value`` a float in [0, 1) that
    parametrizes it. Every mutation keeps the arrays well-formed (the readers' job)."""
    name, u = op
    cams, poses = scene.cameras, scene.poses
    V, N = len(cams), len(poses)
    kp = poses.keypoints.copy()

    def with_poses(p: Poses2D) -> Scene:
        return Scene(scene.name, cams, p)

    def with_cameras(c: Cameras) -> Scene:
        return Scene(scene.name, c, poses)

    if name == "drop_frames" and V:
        keep_views = rng.random(V) >= u
        return with_poses(poses.subset(np.flatnonzero(keep_views[poses.view])))
    if name == "one_frame" and N:
        return with_poses(poses.subset(np.flatnonzero(poses.view == poses.view[int(u * N)])))
    if name == "drop_poses" and N:
        return with_poses(poses.subset(np.flatnonzero(rng.random(N) >= u)))
    if name == "duplicate_poses" and N:
        extra = rng.integers(0, N, 1 + int(u * 3 * N))
        idx = np.concatenate([np.arange(N), extra])
        app = None if poses.appearance is None else poses.appearance[idx]
        return with_poses(Poses2D(poses.keypoints[idx], poses.view[idx], np.arange(len(idx)),
                                  poses.score[idx], app))
    if name == "extreme_keypoints" and N:
        scale = 10.0 ** (-6 + 18 * u)
        chosen = rng.random(N) < 0.5
        kp[chosen, :, :2] = kp[chosen, :, :2] * scale - rng.normal(0, scale, (int(chosen.sum()), 17, 2))
    elif name == "zero_confidence" and N:
        kp[rng.random(N) < 0.3 + 0.7 * u, :, 2] = 0.0
    elif name == "random_confidence" and N:
        kp[..., 2] = rng.random(kp.shape[:2]) ** (1 + 5 * u)
    elif name == "shuffle_views" and N:
        view = np.where(rng.random(N) < u, rng.integers(0, V, N), poses.view)
        return with_poses(Poses2D(kp, view, poses.ids, poses.score, poses.appearance))
    elif name == "zero_scores":
        return with_poses(Poses2D(kp, poses.view, poses.ids, poses.score * u * 0.1, poses.appearance))
    elif name == "appearance" and poses.appearance is not None:
        app = poses.appearance * (0.0 if u < 0.5 else -1.0)
        return with_poses(Poses2D(kp, poses.view, poses.ids, poses.score, app if u < 0.9 else None))
    elif name == "swap_cameras" and V > 1:
        order = np.arange(V)
        a, b = rng.choice(V, 2, replace=False)
        order[a], order[b] = b, a
        return with_cameras(Cameras(cams.K[order], cams.R[order], cams.t[order], cams.size, cams.names))
    elif name == "identical_cameras":
        first = np.zeros(V, dtype=int)
        c = cams.subset(first)
        return with_cameras(Cameras(c.K, c.R, c.t, c.size, cams.names))
    elif name == "focal":
        K = cams.K.copy()
        K[:, :2, :2] *= 10.0 ** (-6 + 15 * u)
        return with_cameras(Cameras(K, cams.R, cams.t, cams.size, cams.names))
    elif name == "cameras_at_infinity":
        return with_cameras(Cameras(cams.K, cams.R, cams.t * 10.0 ** (3 + 12 * u), cams.size, cams.names))
    elif name == "collapse_cameras":                      # all centres within u·1e-9 of the first
        centers = cams.centers[:1] + (cams.centers - cams.centers[:1]) * 1e-9 * u
        t = -np.einsum("vij,vj->vi", cams.R, centers)
        return with_cameras(Cameras(cams.K, cams.R, t, cams.size, cams.names))
    elif name == "facing_away" and V:
        return with_cameras(_rotate_away(cams, np.flatnonzero(rng.random(V) < 0.2 + 0.8 * u)))
    elif name == "points_at_infinity" and N:
        chosen = rng.random(kp.shape[:2]) < u
        kp[chosen, :2] = 1e15
    elif name == "non_finite" and N:                      # must be refused with an InputError
        kp[int(u * N), int(u * 17) % 17, int(u * 3) % 3] = [np.nan, np.inf, -np.inf][int(u * 3) % 3]
    return with_poses(Poses2D(kp, poses.view, poses.ids, poses.score, poses.appearance))


MUTATIONS = ("drop_frames", "one_frame", "drop_poses", "duplicate_poses", "extreme_keypoints",
             "zero_confidence", "random_confidence", "shuffle_views", "zero_scores", "appearance",
             "swap_cameras", "identical_cameras", "focal", "cameras_at_infinity", "collapse_cameras",
             "facing_away", "points_at_infinity", "non_finite")

unit = st.floats(0, 1, exclude_max=True, allow_nan=False)
mutations = st.lists(st.tuples(st.sampled_from(MUTATIONS), unit), min_size=1, max_size=4)
configs = st.fixed_dictionaries({
    "refine": st.booleans(),
    "ransac": st.booleans(),
    "tau": st.sampled_from([0.0, 0.05, 0.2, 0.45]),
    "min_group_size": st.integers(1, 4),
    "min_views": st.integers(2, 3),
    "min_person_joints": st.sampled_from([1, 5, 17]),
    "use_appearance": st.booleans(),
    "merge_distance": st.sampled_from([0.0, 0.3, 5.0]),
})
cases = st.tuples(st.integers(0, 3), mutations, configs, st.integers(0, 2**16))


def mutated_scene(base: int, ops: list, seed: int) -> Scene:
    rng = np.random.default_rng(seed)
    scene = base_scenes()[base]
    for op in ops:
        scene = apply_mutation(scene, op, rng)
    return scene


def check_result(result, scene: Scene) -> None:
    """The output contract: finite or NaN (never inf), shapes consistent, a JSON document
    without NaN or infinity."""
    from mvm.io.scene_dir import poses3d_document

    persons = result.persons
    P = len(persons)
    X = persons.keypoints3d
    assert X.shape == (P, 17, 3)
    assert not np.isinf(X).any()
    assert (np.isnan(X).all(-1) | np.isfinite(X).all(-1)).all()        # a joint is whole or null
    assert np.isfinite(persons.scores).all()
    assert not np.isinf(persons.reprojection_error_px).any()
    assert len(persons.members) == P
    for m in persons.members:
        assert len(set(scene.poses.view[m].tolist())) == len(m)        # one pose per view
    document = poses3d_document(persons, scene.poses, result.metrics, {"warnings": result.warnings})
    json.dumps(document, allow_nan=False)


def run_case(base: int, ops: list, config_values: dict, seed: int) -> str:
    """Run one in-memory case; returns ``"result"`` or ``"refused"``; anything else raises."""
    scene = mutated_scene(base, ops, seed)
    config = Config(**config_values)
    try:
        result = reconstruct(scene, config)
    except InputError as e:
        assert str(e) and "\n" not in str(e)
        return "refused"
    check_result(result, scene)
    return "result"


@settings(max_examples=60, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(cases)
def test_reconstruct_on_mutated_scenes(case):
    base, ops, config_values, seed = case
    run_case(base, ops, config_values, seed)


def test_non_finite_keypoints_are_refused():
    scene = mutated_scene(1, [("non_finite", 0.5)], 0)
    with pytest.raises(InputError, match="non-finite"):
        reconstruct(scene, Config())


def test_unmutated_base_scenes_reconstruct_their_people():
    """The fuzzing starts from scenes that work: every base scene finds people."""
    for scene in base_scenes():
        result = reconstruct(scene, Config(refine=False))
        assert len(result.persons) >= 1
        check_result(result, scene)


# --- on disk, through the command line ------------------------------------------------------

FILE_MUTATIONS = ("truncate", "garbage", "delete", "huge_number", "nan_literal", "none")


def mutate_files(scene_dir: Path, op: str, u: float) -> None:
    """Damage one file of a written scene directory."""
    files = sorted(p for p in scene_dir.rglob("*") if p.is_file())
    if not files or op == "none":
        return
    target = files[int(u * len(files)) % len(files)]
    data = target.read_bytes()
    if op == "truncate":
        target.write_bytes(data[: int(u * len(data))])
    elif op == "garbage":
        at = int(u * len(data))
        target.write_bytes(data[:at] + bytes(np.random.default_rng(at).integers(0, 256, 16, dtype=np.uint8))
                           + data[at + 16:])
    elif op == "delete":
        target.unlink()
    elif op in ("huge_number", "nan_literal") and target.suffix == ".json":
        text = data.decode()
        digits = [i for i, c in enumerate(text) if c.isdigit()]
        if digits:
            at = digits[int(u * len(digits))]
            text = text[:at] + ("1e308" if op == "huge_number" else "NaN") + text[at + 1:]
            target.write_text(text)


def run_cli_case(tmp: Path, base: int, ops: list, file_op: tuple, seed: int, refine: bool) -> str:
    """Write a mutated scene, damage a file, run ``mvm reconstruct``: exit 0 with a valid
    output, or exit 2 with one error line and no output. Returns ``"result"``/``"refused"``."""
    from click.testing import CliRunner

    from mvm.cli.main import main
    from mvm.io.scene_dir import write_scene

    scene = mutated_scene(base, ops, seed)
    if len(scene.poses) == 0:
        scene = base_scenes()[base]
    bad = ~np.isfinite(scene.poses.keypoints).all(axis=(1, 2))
    if bad.any():                                           # JSON cannot carry NaN: readers' job
        scene = Scene(scene.name, scene.cameras, scene.poses.subset(np.flatnonzero(~bad)))
        if len(scene.poses) == 0:
            scene = base_scenes()[base]
    try:
        write_scene(tmp, scene.cameras, scene.poses, binary=bool(seed % 2))
    except (ValueError, InputError):
        return "refused"                                    # e.g. a camera the writer refuses
    mutate_files(tmp, *file_op)
    args = ["reconstruct", str(tmp), "--set", "min_group_size=2"] + ([] if refine else ["--no-refine"])
    result = CliRunner().invoke(main, args)
    output = tmp / "mvm" / "poses3d.json"
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    if result.exit_code == 0:
        document = json.loads(output.read_text())
        for person in document["persons"]:
            for joint in person["keypoints3d"]:
                assert all(v is None or math.isfinite(v) for v in joint)
        return "result"
    assert result.exit_code == 2, result.output
    assert "mvm: error:" in result.output and "Traceback" not in result.output
    assert not output.exists()
    return "refused"


cli_cases = st.tuples(st.integers(0, 3), st.lists(st.tuples(st.sampled_from(MUTATIONS), unit), max_size=2),
                      st.tuples(st.sampled_from(FILE_MUTATIONS), unit), st.integers(0, 2**16), st.booleans())


@settings(max_examples=15, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(cli_cases)
def test_cli_on_mutated_scene_directories(tmp_path_factory, case):
    base, ops, file_op, seed, refine = case
    run_cli_case(tmp_path_factory.mktemp("fuzz") / "scene", base, ops, file_op, seed, refine)
