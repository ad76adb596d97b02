"""The scene-directory drivers: many scenes in one call give the files and results of one
scene at a time, in order, each scene's failure its own."""
from __future__ import annotations

import json

import numpy as np
import pytest

from mvm.core.config import Config
from mvm.errors import InputError
from mvm.io.scene_dir import read_scene, write_scene
from mvm.sim.simulate import SimConfig, simulate


@pytest.fixture(scope="module")
def three(tmp_path_factory, bank_poses):
    root = tmp_path_factory.mktemp("many")
    truths = {}
    for seed, name in enumerate(("a", "b", "c")):
        scene, truth = simulate(SimConfig(people=2, frames=12, seed=20 + seed), bank_poses)
        write_scene(root / name, scene.cameras, scene.poses)
        truths[name] = truth
    return root, truths


def _numbers(path):
    """The document, which holds nothing of the run (its seconds are in ``timings.json``)."""
    return json.loads(path.read_text())


def test_many_scenes_give_what_one_at_a_time_gives(three, tmp_path):
    from mvm.scenes import reconstruct_dir, reconstruct_dirs

    root, truths = three
    config = Config(refine=False)
    paths = [root / n for n in ("c", "a", "b")]
    outcomes = list(reconstruct_dirs(paths, config, "many"))
    assert [p for p, _ in outcomes] == paths                                       # in order
    for path, result in outcomes:
        single = reconstruct_dir(path, config, "one")
        assert _numbers(path / "many" / "poses3d.json") == _numbers(path / "one" / "poses3d.json")
        np.testing.assert_array_equal(result.persons.keypoints3d, single.persons.keypoints3d)
        assert len(result.persons) == len(truths[path.name].poses3d)                # both people found
        assert not list((path / "many").glob(".*.tmp"))                            # no temporary left


def test_refined_in_batches_as_one_at_a_time(three, monkeypatch):
    """Scenes refined together give each scene's numbers to rounding; a batch closes at
    ``BATCH_SCENES`` scenes or ``BATCH_POSES`` 2D poses."""
    from mvm import scenes
    from mvm.scenes import reconstruct_dir, reconstruct_dirs

    root, _ = three
    paths = [root / n for n in ("a", "b", "c", "a")]
    sizes, real = [], scenes.reconstruct_many

    def recorded(batch, *args, **kwargs):
        sizes.append([s.name for s in batch])
        return real(batch, *args, **kwargs)

    monkeypatch.setattr(scenes, "reconstruct_many", recorded)
    monkeypatch.setattr(scenes, "BATCH_SCENES", 3)
    outcomes = list(reconstruct_dirs(paths, Config(), "batched", workers=1))
    assert sizes == [["a", "b", "c"], ["a"]]
    poses = [len(read_scene(p).poses) for p in paths]
    sizes.clear()
    monkeypatch.setattr(scenes, "BATCH_POSES", max(poses) + 1)      # any two scenes reach it
    list(reconstruct_dirs(paths, Config(), "batched", workers=1))
    assert sizes == [["a", "b"], ["c", "a"]]
    for path, result in outcomes:
        alone = reconstruct_dir(path, Config(), "alone")
        np.testing.assert_allclose(result.persons.keypoints3d, alone.persons.keypoints3d, rtol=0, atol=1e-9)
        assert result.metrics == pytest.approx(alone.metrics, rel=1e-9, nan_ok=True)


def test_a_scene_that_fails_to_read_or_write_is_its_own_failure(three, monkeypatch):
    from mvm import scenes
    from mvm.scenes import reconstruct_dirs

    root, _ = three
    real = scenes.write_poses3d

    def refused(path, document):
        if path.parent.parent.name == "b":
            raise InputError(path, None, "cannot write: no space left on the device")
        real(path, document)

    monkeypatch.setattr(scenes, "write_poses3d", refused)
    paths = [root / "missing", root / "a", root / "b", root / "c"]
    outcomes = dict(reconstruct_dirs(paths, Config(refine=False), "fails"))
    assert list(outcomes) == paths
    assert isinstance(outcomes[root / "missing"], InputError)
    assert "no space left" in str(outcomes[root / "b"]) and not (root / "b" / "fails" / "poses3d.json").exists()
    for name in ("a", "c"):
        assert len(outcomes[root / name].persons) == 2
        assert (root / name / "fails" / "poses3d.json").is_file()


@pytest.fixture(scope="module")
def nine(three, tmp_path_factory):
    """Nine scene directories (copies of the three simulated ones), the fourth without its 2D poses."""
    import shutil

    root, _ = three
    many = tmp_path_factory.mktemp("nine")
    paths = []
    for k in range(9):
        path = many / f"s{k}"
        shutil.copytree(root / "abc"[k % 3], path)
        paths.append(path)
    (paths[3] / "poses2d.json").unlink()
    return paths


def _logged_reads(monkeypatch, pids_file):
    """Make every read of a scene log a warning naming it and note which process read it."""
    import logging
    import os
    import warnings

    from mvm import scenes

    real = scenes.read_scene

    parent = os.getpid()

    def noted(path):
        with open(pids_file, "a") as f:
            f.write(f"{os.getpid()} {path.name}\n")
        logging.getLogger("mvm.scenes").warning("reading %s", path.name)
        if os.getpid() != parent:
            warnings.warn(f"a Python warning in a worker, reading {path.name}", stacklevel=1)
        return real(path)

    monkeypatch.setattr(scenes, "read_scene", noted)


def test_two_workers_give_the_files_outcomes_and_log_of_one(nine, tmp_path, monkeypatch, caplog, capfd):
    import os

    from mvm.scenes import reconstruct_dirs

    _logged_reads(monkeypatch, tmp_path / "pids")
    config = Config(refine=False)
    runs = {}
    for workers in (1, 2):
        caplog.clear()
        (tmp_path / "pids").write_text("")
        runs[workers] = (list(reconstruct_dirs(nine, config, f"w{workers}", workers=workers)),
                         [r.getMessage() for r in caplog.records if r.name == "mvm.scenes"],
                         [line.split() for line in (tmp_path / "pids").read_text().splitlines()])
    (one, one_log, one_pids), (two, two_log, two_pids) = runs[1], runs[2]
    assert [p for p, _ in two] == [p for p, _ in one] == nine                       # in order
    assert two_log == one_log == [f"reading s{k}" for k in range(9)]                 # the workers' log, in place
    caught = [r.getMessage() for r in caplog.records if r.name == "py.warnings"]
    assert len(caught) == 5 and all("a Python warning in a worker" in m for m in caught)
    assert "Python warning" not in capfd.readouterr().err                          # a worker writes nothing
    assert {pid for pid, _ in one_pids} == {str(os.getpid())}
    worker = {name for pid, name in two_pids if pid != str(os.getpid())}
    assert worker == {f"s{k}" for k in range(4, 9)}                                  # the second share, elsewhere
    for (path, a), (_, b) in zip(one, two):
        if path.name == "s3":
            assert isinstance(a, InputError) and isinstance(b, InputError) and str(a) == str(b)
            assert not (path / "w2").exists() or not (path / "w2" / "poses3d.json").exists()
            continue
        assert _numbers(path / "w1" / "poses3d.json") == _numbers(path / "w2" / "poses3d.json")
        np.testing.assert_array_equal(a.persons.keypoints3d, b.persons.keypoints3d)
        assert a.metrics == b.metrics


def test_a_killed_or_missing_worker_loses_no_scene(nine, tmp_path, monkeypatch):
    import os
    import signal

    from mvm import scenes
    from mvm.scenes import reconstruct_dirs

    parent, real = os.getpid(), scenes.read_scene

    def killed_in_worker(path):
        if os.getpid() != parent and path.name == "s7":                             # after two scenes written
            os.kill(os.getpid(), signal.SIGKILL)
        return real(path)

    config = Config(refine=False)
    reference = list(reconstruct_dirs(nine, config, "ref", workers=1))
    monkeypatch.setattr(scenes, "read_scene", killed_in_worker)
    monkeypatch.setattr(scenes, "BATCH_SCENES", 1)                  # the worker writes s4, s5 before s7
    outcomes = {"killed": list(reconstruct_dirs(nine, config, "killed", workers=2))}

    def no_fork():
        raise OSError(11, "Resource temporarily unavailable")

    monkeypatch.setattr(os, "fork", no_fork)                                         # no worker to be had
    outcomes["unforked"] = list(reconstruct_dirs(nine, config, "unforked", workers=2))
    for output, got in outcomes.items():
        assert [p for p, _ in got] == [p for p, _ in reference] == nine
        for (path, outcome), (_, expected) in zip(got, reference):
            if path.name == "s3":
                assert isinstance(outcome, InputError) and str(outcome) == str(expected)
            else:
                assert outcome.metrics == expected.metrics and len(outcome.persons) == 2
                assert _numbers(path / output / "poses3d.json") == _numbers(path / "ref" / "poses3d.json")
                assert not list((path / output).glob(".*.tmp"))


def test_the_command_recaps_tab_separated_in_a_pipe_and_checks_workers(three):
    from click.testing import CliRunner

    from mvm.cli.main import main
    from mvm.cli.scene import RECAP_COLUMNS

    root, truths = three
    paths = [str(root / n) for n in ("a", "b")]
    run = CliRunner().invoke(main, ["reconstruct", *paths, "--no-refine", "--output-name", "cli", "--workers", "2"])
    assert run.exit_code == 0, run.output
    lines = [line.split("\t") for line in run.stdout.splitlines() if not line.startswith("# ")]
    assert lines[0] == list(RECAP_COLUMNS) and [row[0] for row in lines[1:]] == paths
    assert [int(row[1]) for row in lines[1:]] == [len(truths[n].poses3d) for n in ("a", "b")]
    run = CliRunner().invoke(main, ["reconstruct", *paths, "--workers", "0"])
    assert run.exit_code == 2 and "--workers" in run.stderr and "Traceback" not in run.output
