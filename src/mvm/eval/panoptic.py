"""Evaluation on the real CMU Panoptic sample: real cameras and real 3D poses, 2D detections
simulated from them with a detector's errors (:mod:`mvm.sim.rig`), reconstructed with a
subset of the HD cameras and scored with MPJPE, PA-MPJPE, PCP, AP and the fraction of persons
found. World in metres (the files' centimetres / 100, read by :mod:`mvm.io.panoptic_bodies`)."""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mvm.core.config import Config
from mvm.core.scene import Cameras, Poses2D
from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration
from mvm.io.panoptic_bodies import read_panoptic_coco19, read_panoptic_ids
from mvm.io.panoptic_calib import read_panoptic_calibration
from mvm.metrics.mocap_scores import average_precision, pcp
from mvm.metrics.poses import MATCH_DISTANCE_M, match_persons, pose_errors
from mvm.rig.instants import reconstruct_instants, rig_poses
from mvm.sim.detector import DetectorErrors, pose_scores
from mvm.sim.rig import detect_views


def metric_calibration(calibration: RigCalibration) -> RigCalibration:
    """The calibration with the world in metres (translations / 100)."""
    c = calibration.cameras
    return RigCalibration(replace(c, t=c.t / 100.0), {**calibration.metadata, "units": "m"})


def spread_cameras(cameras: Cameras, n: int) -> np.ndarray:
    """``n`` camera indices spread around the dome: farthest-point sampling of the viewing
    directions, from camera 0. ``-> (n,)``."""
    direction = cameras.R[:, 2]                                                    # optical axes
    chosen = [0]
    best = 1 - direction @ direction[0]
    for _ in range(min(n, len(cameras)) - 1):
        k = int(np.argmax(best))
        chosen.append(k)
        best = np.minimum(best, 1 - direction @ direction[k])
    return np.sort(np.array(chosen))


@dataclass
class PanopticSample:
    calibration: RigCalibration
    poses: list[np.ndarray]                                                        # per instant (G, 17, 3), metres
    ids: list[np.ndarray]


def load_sample(sequence_dir: str | Path) -> PanopticSample:
    """The HD cameras and every ``body3DScene`` of ``sequence_dir`` (sorted by frame number)."""
    sequence_dir = Path(sequence_dir)
    calibs = sorted(sequence_dir.glob("calibration_*.json"))
    if not calibs:
        raise InputError(sequence_dir, None, "no calibration_*.json")
    calibration = metric_calibration(read_panoptic_calibration(calibs[0]))
    files = sorted(sequence_dir.glob("hdPose3d_stage1_coco19/body3DScene_*.json"),
                   key=lambda p: int(p.stem.split("_")[-1]))
    poses, ids = [], []
    for f in files:
        poses.append(read_panoptic_coco19(f))
        ids.append(np.array(read_panoptic_ids(f), dtype=int))
    return PanopticSample(calibration, poses, ids)


def simulate_detections(sample: PanopticSample, cameras_index: np.ndarray, seed: int,
                        errors: DetectorErrors = DetectorErrors()) -> Poses2D:
    """Distorted 2D detections of every instant in the chosen cameras, then undistorted with
    the calibration (as a real pipeline does)."""
    from mvm.rig.rigdir import subset_calibration, undistort

    calibration = subset_calibration(sample.calibration, cameras_index)
    rng = np.random.default_rng(seed)
    kps, cams, inst = [], [], []
    for t, X in enumerate(sample.poses):
        k, c, _ = detect_views(calibration.cameras, X, rng, errors)
        kps.append(k)
        cams.append(c)
        inst.append(np.full(len(c), t))
    keypoints = np.concatenate(kps)
    camera = np.concatenate(cams)
    keypoints = undistort(calibration, keypoints, camera)
    return rig_poses(keypoints, np.concatenate(inst), camera, pose_scores(keypoints))


def evaluate(sample: PanopticSample, n_cameras: int, config: Config, seeds: int = 3,
             errors: DetectorErrors = DetectorErrors(), match_distance_m: float = MATCH_DISTANCE_M) -> dict:
    """Reconstruct the sample with ``n_cameras`` spread cameras, ``seeds`` detector draws.
    Returns MPJPE / PA-MPJPE (mm) of the persons found (MPJPE <= ``match_distance_m``), PCP,
    AP, the fraction of persons found, instants/s."""
    index = spread_cameras(sample.calibration.cameras, n_cameras)
    cameras = sample.calibration.cameras.subset(index)
    estimates, truths, ids, scores = [], [], [], []
    mpjpe, pa, found, total, seconds = [], [], 0, 0, 0.0
    for seed in range(seeds):
        det = simulate_detections(sample, index, seed, errors)
        t0 = time.perf_counter()
        persons = reconstruct_instants(cameras, det, config)
        seconds += time.perf_counter() - t0
        for t, X_true in enumerate(sample.poses):
            X = persons.X[persons.instant == t]
            pairs = match_persons(X, X_true, match_distance_m)
            e = pose_errors(X, X_true, pairs)
            if e["evaluated_persons"]:
                mpjpe += [e["mpjpe"]] * e["evaluated_persons"]
                pa += [e["pa_mpjpe"]] * e["evaluated_persons"]
            found += len(pairs)
            total += len(X_true)
            estimates.append(X)
            scores.append(np.nanmean(persons.scores[persons.instant == t], axis=1) if len(X) else np.zeros(0))
            truths.append(X_true)
            ids.append(sample.ids[t])
    ap = average_precision(estimates, scores, truths)
    return {"cameras": int(n_cameras), "camera_names": [cameras.names[i] for i in range(len(cameras))],
            "mpjpe_mm": 1000 * float(np.mean(mpjpe)) if mpjpe else float("nan"),
            "pa_mpjpe_mm": 1000 * float(np.mean(pa)) if pa else float("nan"),
            "pcp": pcp(estimates, truths, ids)["average"], "found": found / max(total, 1),
            **ap, "instants_per_s": len(sample.poses) * seeds / max(seconds, 1e-9)}
