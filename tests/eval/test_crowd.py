"""The frozen-crowd benchmark: its scenes are what the issue asks for, and its quick mode runs
end to end with the oracle beside every method."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from mvm.core.config import Config
from mvm.eval.crowd import CROWD_RANGES, crowd_config, pelvis_spacing, run_crowd, true_groups
from mvm.sim.simulate import simulate


@pytest.fixture(scope="module")
def crowd():
    sim = crowd_config(3, frames=100)
    return sim, *simulate(sim)


def test_crowd_scene_is_as_dense_as_a_real_frozen_crowd(crowd):
    sim, scene, truth = crowd
    lo, hi = CROWD_RANGES["people"]
    assert lo <= sim.people <= hi and len(truth.poses3d) == sim.people
    spacing = pelvis_spacing(truth.poses3d)
    assert spacing.min() >= 0.6 - 0.02 and spacing.max() <= 1.0 + 0.02           # nearest neighbours
    pelvis = truth.poses3d[:, [11, 12], :2].mean(1)
    close = np.linalg.norm(pelvis[:, None] - pelvis[None], axis=-1)[np.triu_indices(sim.people, 1)] < 0.8
    assert close.sum() >= 3
    assert {"standing", "sitting"} <= set(truth.labels)
    centers = scene.cameras.centers
    assert np.all(np.abs(centers[:, 2] - sim.camera_height) < 0.15) and 1.4 <= sim.camera_height <= 1.8
    distance = np.linalg.norm(centers[:, :2], axis=1)
    assert 4.0 - 0.2 <= distance.min() and distance.max() <= 7.0 + 0.2
    heading = np.unwrap(np.arctan2(centers[:, 1], centers[:, 0]))
    assert np.degrees(np.ptp(heading)) == pytest.approx(sim.arc_deg, abs=3) and 40 <= sim.arc_deg <= 90


def test_crowd_detector_errors(crowd):
    sim, scene, truth = crowd
    true = truth.person >= 0
    assert (~true).sum() / true.sum() == pytest.approx(0.1, abs=0.04)           # false poses 10 % of the true
    from mvm.sim.projection import project_people

    uv, _ = project_people(scene.cameras, truth.poses3d)
    kp = scene.poses.keypoints[true]
    exact = uv[scene.poses.view[true], truth.person[true]]                        # (N, 17, 2)
    present = kp[..., 2] > 0
    size = np.ptp(exact, axis=1).max(axis=1)                                      # person's image size
    error = np.linalg.norm(kp[..., :2] - exact, axis=-1) / size[:, None]
    # Median radial error of a 2D Gaussian of sigma s per axis: s * sqrt(2 ln 2).
    assert np.median(error[present]) / np.sqrt(2 * np.log(2)) == pytest.approx(0.015, rel=0.2)


def test_true_groups_cover_every_true_pose():
    person = np.array([0, 2, -1, 0, 2, 2, -1])
    groups = true_groups(person)
    assert [g.tolist() for g in groups] == [[0, 3], [1, 4, 5]]


def test_quick_crowd_benchmark(tmp_path):
    from mvm.eval.bench_files import write_crowd_report

    result = run_crowd(quick=True, methods=[("paper", Config())])
    assert [(r["method"], r["cues"]) for r in result.rows] == [("paper", "geometry"),
                                                                ("paper", "geometry + appearance")]
    for row in result.rows + result.sweep_rows:
        assert row["oracle_precision"] == row["oracle_recall"] == 1.0
        assert row["oracle_persons"] == row["oracle_found"] == row["oracle_true"] == row["people"]
        assert row["oracle_mpjpe_mm"] < 60 and 2 < row["oracle_E_R_px"] < 15
        assert row["precision"] > 0.85 and row["recall"] > 0.8 and row["found"] >= row["true"] - 1
    assert {(r["axis"], r["value"]) for r in result.sweep_rows} == {("people", 5), ("people", 10),
                                                                   ("arc_deg", 20.0), ("arc_deg", 90.0)}
    path = write_crowd_report(result, tmp_path, "python benchmarks/crowd.py --quick", 1.0)
    text = path.read_text()
    assert "paper's E_R on real videos: 14.6 px" in text and "Sweep of arc_deg" in text
    with open(tmp_path / "crowd.csv") as f:
        assert len(list(csv.DictReader(f))) == len(result.rows)
    assert len(json.loads((tmp_path / "crowd.json").read_text())["sweep_rows"]) == len(result.sweep_rows)
