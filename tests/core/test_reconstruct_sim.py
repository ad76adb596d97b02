"""Acceptance on simulated mannequin scenes with ground truth (real poses from the bank)."""
from __future__ import annotations

import numpy as np
import pytest

from mvm.core.config import Config
from mvm.core.reconstruct import reconstruct
from mvm.eval.demo import evaluate
from mvm.sim.simulate import SimConfig, simulate


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_crowd_of_six_hundred_frames(seed):
    scene, truth = simulate(SimConfig(people=6, frames=100, seed=seed))
    result = reconstruct(scene, Config())
    report = evaluate(result, truth)
    assert report["precision"] >= 0.99, report
    assert report["recall"] >= 0.95, report
    assert report["persons_found"] == 6, report
    assert report["mpjpe_mm"] <= 30.0, report
    assert report["pa_mpjpe_mm"] <= 30.0, report
    assert result.metrics["E_R_px"] < 10


def test_refinement_lowers_reprojection_error_on_a_scene():
    scene, truth = simulate(SimConfig(people=4, frames=60, seed=5))
    plain = reconstruct(scene, Config(refine=False))
    refined = reconstruct(scene, Config(refine=True))
    assert refined.metrics["E_R_px"] <= plain.metrics["E_R_px"] + 1e-6
    moved = np.linalg.norm(refined.persons.keypoints3d - plain.persons.keypoints3d, axis=-1)
    well_observed = plain.persons.views_per_joint >= 20
    assert np.nanmax(moved[well_observed]) < 0.05          # metres


def test_without_ransac_outliers_raise_the_error():
    scene, truth = simulate(SimConfig(people=4, frames=60, seed=6).replace(outlier_joint_prob=0.05))
    with_ransac = reconstruct(scene, Config(refine=False))
    without = reconstruct(scene, Config(refine=False, ransac=False))
    assert with_ransac.metrics["E_R_px"] < without.metrics["E_R_px"]
    assert without.metrics["outliers"] == 0
    assert evaluate(with_ransac, truth)["mpjpe_mm"] < evaluate(without, truth)["mpjpe_mm"]


def test_same_scene_same_result():
    scene, _ = simulate(SimConfig(people=3, frames=40, seed=7))
    a = reconstruct(scene, Config())
    b = reconstruct(scene, Config())
    assert np.array_equal(np.nan_to_num(a.persons.keypoints3d), np.nan_to_num(b.persons.keypoints3d))


def test_demo_command(tmp_path):
    from click.testing import CliRunner

    from mvm.cli.main import main

    result = CliRunner().invoke(main, ["demo", "--people", "3", "--frames", "30", "-o", str(tmp_path / "d")])
    assert result.exit_code == 0, result.output
    assert "matching precision" in result.output and "MPJPE" in result.output
    assert (tmp_path / "d" / "scene" / "mvm" / "poses3d.json").is_file()
    assert (tmp_path / "d" / "scene.groundtruth.json").is_file()
