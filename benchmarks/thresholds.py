"""Thresholds in the data's units: the reconstruction's settings against fixed pixel values and
the oracle, on real camera geometry and real poses with simulated detectors.

    python benchmarks/thresholds.py [--seeds 2] [--crowd-seeds 2] [--cases dome18,dome31,crowd,levels]
        [--sequence PATH] [--set NAME=key=value[,key=value] ...]

Cases:

- ``dome18``: the real CMU Panoptic dome (HD calibration with lens distortion, real 3D poses of
  three people over 20 instants), 18 cameras spread around it, heavy detector errors (noise 3 %
  of the person's size, 15 % dropout, 5 % swaps, 4 % outlier joints, false poses 40 % of the
  true ones).
- ``dome31``: the same dome, all 31 cameras, the default detector (:class:`mvm.sim.detector.DetectorErrors`,
  as ``benchmarks/rig_panoptic.py``'s first table).
- ``crowd``: frozen crowds of 8-15 people filmed by one hand-held 1080p camera
  (:func:`mvm.eval.crowd.crowd_config`).
- ``levels``: the 18-camera dome seen by each detector of :data:`mvm.sim.detector.DETECTOR_LEVELS`
  (noise 0.5 % to 3 % of the person's size), the default beside the oracle.

Rows: the default settings (the RANSAC threshold follows each scene's noise), thresholds held
at hand-set values (person sizes), and the oracle (the true grouping, RANSAC over every pair of
views, no refinement, the default thresholds).
Columns: recall (true persons found within 0.5 m), spurious persons (estimated persons matching
no true one, per seed), MPJPE (mm, over the persons found).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from mvm.core.config import Config
from mvm.core.pipeline import reconstruct_poses
from mvm.core.reconstruct import reconstruct, scene_config
from mvm.eval.crowd import crowd_config, true_groups
from mvm.eval.panoptic import load_sample, spread_cameras
from mvm.metrics.poses import MATCH_DISTANCE_M, match_persons, person_errors
from mvm.rig.instants import reconstruct_instants, rig_poses
from mvm.rig.rigdir import subset_calibration, undistort
from mvm.sim.detector import DETECTOR_LEVELS, DetectorErrors, detector_level, pose_scores
from mvm.sim.rig import detect_views
from mvm.sim.simulate import simulate

SEQUENCE = Path(__file__).resolve().parents[2] / "shared" / "data" / "panoptic" / "160906_band1"
#: The heavy detector of the 18-camera case; false poses are 40 % of the true ones (3 people).
HEAVY = detector_level("heavy", 3)
#: Hypotheses enough for the oracle's RANSAC to try every pair of views (C(31, 2) = 465).
EXHAUSTIVE = 1000


#: The settings compared: the default, and hand-set RANSAC thresholds held for every scene.
ROWS = [("default", {}),
        ("held 0.05", {"ransac_threshold": 0.05, "ransac_threshold_sigmas": 0.0}),
        ("held 0.1", {"ransac_threshold": 0.1, "ransac_threshold_sigmas": 0.0}),
        ("held 0.15", {"ransac_threshold": 0.15, "ransac_threshold_sigmas": 0.0}),
        ("held 0.2", {"ransac_threshold": 0.2, "ransac_threshold_sigmas": 0.0})]


def rig_detections(sample, index, seed: int, errors: DetectorErrors):
    """Distorted detections of every instant, undistorted: ``(Poses2D, true person (N,))``."""
    calibration = subset_calibration(sample.calibration, index)
    rng = np.random.default_rng(seed)
    kps, cams, inst, persons = [], [], [], []
    for t, X in enumerate(sample.poses):
        k, c, g = detect_views(calibration.cameras, X, rng, errors)
        kps.append(k)
        cams.append(c)
        inst.append(np.full(len(c), t))
        persons.append(g)
    keypoints, camera = np.concatenate(kps), np.concatenate(cams)
    keypoints = undistort(calibration, keypoints, camera)
    return rig_poses(keypoints, np.concatenate(inst), camera, pose_scores(keypoints)), np.concatenate(persons)


def _score(estimates: list[np.ndarray], truths: list[np.ndarray]) -> tuple[int, int, int, list[float]]:
    """found, true, spurious, per-person MPJPE over the scenes / instants."""
    found = total = spurious = 0
    errors: list[float] = []
    for X, X_true in zip(estimates, truths):
        pairs = match_persons(X, X_true, MATCH_DISTANCE_M)
        mpjpe, _ = person_errors(X, X_true, pairs)
        found += len(pairs)
        total += len(X_true)
        spurious += len(X) - len(pairs)
        errors += mpjpe.tolist()
    return found, total, spurious, errors


def oracle_config(config: Config) -> Config:
    """The scenes' settings (:func:`scene_config`) of the true grouping's reconstruction."""
    return scene_config(config).replace(refine=False, ransac_hypotheses=EXHAUSTIVE, merge_distance=0.0)


class _Tally:
    """One method's scores summed over the draws: persons found, true and spurious, and the
    joint errors of the persons found."""

    def __init__(self):
        self.found = self.total = self.spurious = 0
        self.errors: list[float] = []

    def add(self, found: int, total: int, spurious: int, errors: list[float]) -> None:
        self.found, self.total, self.spurious = self.found + found, self.total + total, self.spurious + spurious
        self.errors += errors

    def summary(self, draws: int) -> dict:
        return {"recall": self.found / max(self.total, 1), "spurious": self.spurious / draws,
                "mpjpe_mm": 1000 * float(np.mean(self.errors)) if self.errors else float("nan")}


def rig_case(sample, n_cameras: int, errors: DetectorErrors, seeds: int, configs) -> dict:
    index = spread_cameras(sample.calibration.cameras, n_cameras)
    cameras = sample.calibration.cameras.subset(index)
    out = {name: _Tally() for name, _ in configs}
    for seed in range(seeds):
        poses, person = rig_detections(sample, index, seed, errors)
        for name, config in configs:
            if name.startswith("oracle"):
                groups = [np.flatnonzero((poses.instant == t) & (person == g))
                          for t in range(len(sample.poses)) for g in range(len(sample.poses[t]))]
                groups = [g for g in groups if len(g) >= 2]
                rec = reconstruct_poses(cameras, poses, oracle_config(config), groups=groups)
                inst = poses.instant[[g[0] for g in rec.groups]]
                keep = rec.stats.keep
                estimates = [rec.stats.X[keep & (inst == t)] for t in range(len(sample.poses))]
            else:
                persons = reconstruct_instants(cameras, poses, config, workers=1)
                estimates = [persons.X[persons.instant == t] for t in range(len(sample.poses))]
            out[name].add(*_score(estimates, sample.poses))
    return {name: tally.summary(seeds) for name, tally in out.items()}


def crowd_case(seeds: int, configs) -> dict:
    out = {name: _Tally() for name, _ in configs}
    for seed in range(seeds):
        scene, truth = simulate(crowd_config(seed))
        for name, config in configs:
            if name.startswith("oracle"):
                # One person at a time: every pair of a person's up to 250 views is too many.
                X = []
                for g in true_groups(truth.person):
                    result = reconstruct(scene, oracle_config(config).replace(ransac_hypotheses=2000), groups=[g])
                    X += list(result.persons.keypoints3d)
                X = np.array(X).reshape(-1, 17, 3)
            else:
                X = reconstruct(scene, config).persons.keypoints3d
            out[name].add(*_score([X], [truth.poses3d]))
    return {name: tally.summary(seeds) for name, tally in out.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2, help="detector draws per dome case")
    parser.add_argument("--crowd-seeds", type=int, default=2, help="crowd scenes")
    parser.add_argument("--cases", default="dome18,dome31,crowd")
    parser.add_argument("--sequence", type=Path, default=SEQUENCE)
    parser.add_argument("--set", dest="sets", action="append", default=[],
                        help="an extra row: name=key=value[,key=value]")
    args = parser.parse_args()
    rows = list(ROWS)
    for spec in args.sets:
        name, _, body = spec.partition("=")
        rows.append((name, {k: float(v) for k, v in (kv.split("=") for kv in body.split(","))}))
    configs = [(name, Config().replace(**changes)) for name, changes in rows] + [("oracle", Config())]
    cases = args.cases.split(",")
    results = {}
    if {"dome18", "dome31", "levels"} & set(cases):
        if not args.sequence.is_dir():
            print(f"Panoptic sample absent: {args.sequence}", file=sys.stderr)
            return 2
        sample = load_sample(args.sequence)
        if "dome18" in cases:
            results["18-camera dome, heavy detector errors"] = rig_case(sample, 18, HEAVY, args.seeds, configs)
        if "dome31" in cases:
            results["31-camera dome, realistic detector"] = rig_case(sample, 31, DetectorErrors(), args.seeds, configs)
        if "levels" in cases:
            for level in DETECTOR_LEVELS:
                results[f"18-camera dome, {level} detector"] = rig_case(
                    sample, 18, detector_level(level, 3), args.seeds, [configs[0], configs[-1]])
    if "crowd" in cases:
        results[f"frozen crowd, one hand-held 1080p camera ({args.crowd_seeds} scenes)"] = crowd_case(
            args.crowd_seeds, configs)
    names = [name for name, _ in configs]
    print("| scene | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for case, r in results.items():
        cells = [f"recall {r[n]['recall']:.3f}, {r[n]['mpjpe_mm']:.2f} mm, {r[n]['spurious']:.2g} spurious"
                 if n in r else "" for n in names]
        print(f"| {case} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
