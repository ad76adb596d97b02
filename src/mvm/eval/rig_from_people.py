"""Checks of a rig set up from its people on the real CMU Panoptic sample (:mod:`mvm.eval.panoptic`):
real cameras and real 3D poses, 2D detections simulated with the detector's errors.

- :func:`sync_check`: per-camera frame offsets applied to the detections, recovered by
  :func:`mvm.rig.synchronize.synchronize`, and the reconstruction (PCP) with the true offsets,
  the recovered ones and none.
- :func:`calibration_check`: the cameras' extrinsics from the people
  (:func:`mvm.rig.calibrate.calibrate_from_people`) against the true ones: camera-centre error
  after the similarity that maps the estimated centres onto the true ones, and PCP with the
  estimated (so mapped) calibration against the true one.
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from mvm.core.config import Config
from mvm.core.geometry import similarity_transform
from mvm.core.scene import Cameras
from mvm.eval.panoptic import PanopticSample, simulate_detections, spread_cameras
from mvm.metrics.mocap_scores import pcp
from mvm.rig.calibrate import calibrate_from_people
from mvm.rig.instants import reconstruct_instants, rig_poses
from mvm.rig.rigdir import subset_calibration, undistort
from mvm.rig.synchronize import fundamental_matrix, synchronize
from mvm.sim.detector import DetectorErrors, pose_scores
from mvm.sim.rig_scene import record_rig


def _pcp(cameras: Cameras, keypoints: np.ndarray, camera: np.ndarray, instant: np.ndarray,
         truths: list[np.ndarray], ids: list[np.ndarray], config: Config) -> float:
    """PCP of reconstructing the poses ``keypoints: (N, 17, 3)`` at ``instant: (N,)`` (indexing
    ``truths``) with ``cameras``."""
    persons = reconstruct_instants(cameras, rig_poses(keypoints, instant, camera, pose_scores(keypoints)), config)
    estimates = [persons.X[persons.instant == t] for t in range(len(truths))]
    return float(pcp(estimates, truths, ids)["average"])


def sync_check(sample: PanopticSample, n_cameras: int, offsets: np.ndarray, seed: int = 0, calibrated: bool = True,
               errors: DetectorErrors = DetectorErrors(), config: Config = Config(refine=False)) -> dict:
    """Recover ``offsets: (n_cameras,)`` (camera ``c``'s frame ``f`` shows instant ``f + offsets[c]``)
    from simulated detections, with the true calibration's epipolar geometry or (``calibrated``
    False) the people's. Returns the true and found offsets (frames to add, :mod:`mvm.io.sync_toml`),
    whether they are ambiguous, and the PCP of the reconstruction with the true offsets, the
    found ones and none, on the instants every camera sees."""
    offsets = np.asarray(offsets, dtype=int)
    index = spread_cameras(sample.calibration.cameras, n_cameras)
    calibration = subset_calibration(sample.calibration, index)
    cams = calibration.cameras
    frames = len(sample.poses) - int(offsets.max() - offsets.min())
    kp, camera, frame, _ = record_rig(calibration, sample.poses, offsets, frames, np.random.default_rng(seed), errors)
    kp = undistort(calibration, kp, camera)
    fundamentals = None
    if calibrated:
        fundamentals = [None] + [fundamental_matrix(cams.K[0], cams.R[0], cams.t[0], cams.K[c], cams.R[c], cams.t[c])
                                 for c in range(1, len(cams))]
    t0 = time.perf_counter()
    result = synchronize(kp, camera, frame, cams.K, frames - 10, fundamentals, seed)
    seconds = time.perf_counter() - t0
    true = offsets - offsets[0]

    # the instants every camera sees; the reference camera's frame g shows instant g + offsets[0] - min
    common = np.arange(offsets.max() - offsets.min(), frames)

    def pcp_with(shift: np.ndarray) -> float:
        """PCP with each camera's frame numbers shifted by ``shift: (V,)``, on the common instants."""
        instant = frame + shift[camera] + offsets[0] - offsets.min()
        keep = np.isin(instant, common)
        return _pcp(cams, kp[keep], camera[keep], np.searchsorted(common, instant[keep]),
                    [sample.poses[s] for s in common], [sample.ids[s] for s in common], config)

    return {"cameras": list(cams.names), "true_offsets": true.tolist(), "found_offsets": result.offsets.tolist(),
            "ambiguous": result.ambiguous.tolist(), "error_px": result.error_px.round(3).tolist(),
            "correlation_peak": result.peak.round(3).tolist(), "seconds": seconds,
            "pcp_true_offsets": pcp_with(true), "pcp_found_offsets": pcp_with(result.offsets),
            "pcp_unsynchronized": pcp_with(np.zeros_like(true))}


def align_cameras(estimated: Cameras, true: Cameras) -> tuple[Cameras, np.ndarray]:
    """``estimated`` moved by the similarity that maps its centres onto ``true``'s (least
    squares): ``(the moved cameras, centre errors (V,))``."""
    s, R, t = similarity_transform(estimated.centers, true.centers)
    R_new = estimated.R @ R.T
    t_new = s * estimated.t - R_new @ t
    moved = Cameras(estimated.K, R_new, t_new, estimated.size, estimated.names)
    return moved, np.linalg.norm(moved.centers - true.centers, axis=1)


def calibration_check(sample: PanopticSample, n_cameras: int, seed: int = 0, errors: DetectorErrors = DetectorErrors(),
                      config: Config = Config(refine=False), focal_error: float = 0.0,
                      refine_focal: bool = False) -> dict:
    """Calibrate ``n_cameras`` spread cameras from the people's simulated detections; compare
    with the true calibration (module docstring). ``focal_error``: the focal lengths given are
    off by this fraction, alternately up and down (camera 0 up; the lens is undone with the true
    calibration); ``refine_focal``: the bundle adjustment adjusts them."""
    index = spread_cameras(sample.calibration.cameras, n_cameras)
    true = sample.calibration.cameras.subset(index)
    det = simulate_detections(sample, index, seed, errors)
    off = 1 + focal_error * np.where(np.arange(n_cameras) % 2 == 0, 1.0, -1.0)
    K = true.K.copy()
    K[:, :2, :2] *= off[:, None, None]
    t0 = time.perf_counter()
    found = calibrate_from_people(det.keypoints, det.view, det.instant, replace(true, K=K), seed, refine_focal)
    seconds = time.perf_counter() - t0
    estimated, K = found.cameras, found.cameras.K
    aligned, centre_error = align_cameras(estimated, true)
    instants = np.arange(len(sample.poses))
    args = (det.keypoints, det.view, det.instant, [sample.poses[t] for t in instants],
            [sample.ids[t] for t in instants], config)
    pairs = np.triu_indices(n_cameras, 1)
    return {"cameras": list(true.names), "centre_error_m": centre_error.round(4).tolist(),
            "mean_centre_error_m": float(centre_error.mean()),
            "scale_error": float(np.median(np.linalg.norm(estimated.centers[:, None] - estimated.centers[None], axis=-1)
                                           [pairs] / np.linalg.norm(true.centers[:, None] - true.centers[None],
                                                                    axis=-1)[pairs]) - 1),
            "focal_error_given": (off - 1).round(4).tolist(),
            "focal_error_found": (K[:, 0, 0] / true.K[:, 0, 0] - 1).round(4).tolist(),
            "residual_px": found.residual_px.round(3).tolist(), "seconds": seconds,
            "pcp_true_calibration": _pcp(true, *args), "pcp_estimated_calibration": _pcp(aligned, *args)}
