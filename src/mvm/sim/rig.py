"""Synthetic rig captures with ground truth: cameras on a ring, people walking, and 2D
detections with a detector's errors (noise proportional to the person's size, occlusion by
other people, dropped joints, left/right swaps, outlier joints, missed and false detections).
World: metres, z up."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mvm.core.keypoints import FLIP_PERMUTATION, NUM_JOINTS
from mvm.core.scene import Cameras
from mvm.io.calib_toml import distort_points
from mvm.sim.simulate import look_at, occluded_joints

#: A standing person (metres, z up, feet on z = 0, facing +y), COCO order.
STANDING = np.array([
    [0, 0.10, 1.62], [-0.03, 0.08, 1.66], [0.03, 0.08, 1.66], [-0.07, 0.0, 1.64], [0.07, 0.0, 1.64],
    [-0.18, 0, 1.42], [0.18, 0, 1.42], [-0.22, 0.02, 1.13], [0.22, 0.02, 1.13], [-0.24, 0.08, 0.88],
    [0.24, 0.08, 0.88], [-0.10, 0, 0.95], [0.10, 0, 0.95], [-0.11, 0.02, 0.52], [0.11, 0.02, 0.52],
    [-0.11, 0, 0.08], [0.11, 0, 0.08]])


@dataclass(frozen=True)
class DetectorErrors:
    """Errors of a simulated 2D detector. ``noise`` is a fraction of the person's image height."""

    noise: float = 0.01
    dropout: float = 0.03
    occlusion: bool = True
    swap_prob: float = 0.01
    outlier_joint_prob: float = 0.02
    false_pose_rate: float = 0.1
    min_visible: int = 5


def ring_cameras(n: int, radius: float = 4.5, height: float = 2.5, focal: float = 1200.0,
                 size: tuple[int, int] = (1920, 1080), names: tuple[str, ...] | None = None) -> Cameras:
    """``n`` cameras evenly on a circle around the origin, looking at (0, 0, 1)."""
    angle = 2 * np.pi * np.arange(n) / n
    centers = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.full(n, height)], 1)
    R = look_at(centers, np.tile([0.0, 0.0, 1.0], (n, 1)))
    t = -np.einsum("vij,vj->vi", R, centers)
    K = np.tile(np.array([[focal, 0, size[0] / 2], [0, focal, size[1] / 2], [0, 0, 1.0]]), (n, 1, 1))
    names = names or tuple(f"cam_{i + 1}" for i in range(n))
    return Cameras(K, R, t, np.tile(size, (n, 1)).astype(float), names)


def walking_people(people: int, instants: int, rng: np.random.Generator, area: float = 1.8,
                   speed: float = 1.2, rate: float = 30.0) -> np.ndarray:
    """``(T, G, 17, 3)`` people walking in straight lines (bouncing inside a square of half-side
    ``area``), swinging arms and legs."""
    start = rng.uniform(-area, area, (people, 2))
    heading = rng.uniform(0, 2 * np.pi, people)
    velocity = speed * np.stack([np.cos(heading), np.sin(heading)], 1) / rate
    time = np.arange(instants)
    raw = start[None] + time[:, None, None] * velocity[None]                     # (T, G, 2)
    pos = area - np.abs(np.mod(raw + area, 4 * area) - 2 * area)                  # reflect into the square
    size = rng.uniform(0.9, 1.1, people)
    phase = 2 * np.pi * 1.8 * time / rate
    swing = np.zeros((instants, people, NUM_JOINTS, 3))
    s = np.sin(phase)[:, None] + 0 * size[None]
    swing[:, :, [9, 16], 1] += 0.25 * s[..., None]
    swing[:, :, [10, 15], 1] -= 0.25 * s[..., None]
    swing[:, :, [7, 14], 1] += 0.1 * s[..., None]
    swing[:, :, [8, 13], 1] -= 0.1 * s[..., None]
    direction = np.diff(pos, axis=0, prepend=pos[:1] - velocity[None])
    yaw = np.arctan2(direction[..., 1], direction[..., 0]) - np.pi / 2            # body faces +y
    c, si = np.cos(yaw), np.sin(yaw)
    body = STANDING[None, None] * size[None, :, None, None] + swing
    x = c[..., None] * body[..., 0] - si[..., None] * body[..., 1]
    y = si[..., None] * body[..., 0] + c[..., None] * body[..., 1]
    return np.stack([x + pos[..., 0:1], y + pos[..., 1:2], body[..., 2]], -1)


def detect_views(cameras: Cameras, poses3d: np.ndarray, rng: np.random.Generator,
                 errors: DetectorErrors = DetectorErrors(), distortions=None,
                 occlusion_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulated detections of one instant in every camera.

    Args:
        poses3d: ``(G, 17, 3)`` true joints (NaN: joint absent in the truth).
        distortions: per camera OpenCV coefficients to distort the pixels with (None: pinhole).
        occlusion_scale: metres per world unit (the occlusion test works in metres).
    Returns:
        ``keypoints (N, 17, 3)`` (distorted pixels when ``distortions``), ``camera (N,)``,
        ``person (N,)`` (-1: a false detection).
    """
    G = len(poses3d)
    kps, cams, persons = [], [], []
    homogeneous = np.concatenate([np.nan_to_num(poses3d), np.ones((G, NUM_JOINTS, 1))], axis=2)
    truth_ok = np.isfinite(poses3d).all(-1)
    for v in range(len(cameras)):
        W, H = cameras.size[v]
        x = homogeneous @ cameras.P[v].T
        depth = x[..., 2]
        uv = x[..., :2] / depth[..., None]
        inside = (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H) & (depth > 0) & truth_ok
        hidden = (occluded_joints(uv, depth * occlusion_scale, cameras.focal[v]) if errors.occlusion
                  else np.zeros_like(inside))
        lo = np.where(inside[..., None], uv, np.inf).min(1)
        hi = np.where(inside[..., None], uv, -np.inf).max(1)
        height = np.where(inside.any(1), (hi - lo).max(-1), 0.0)                # (G,) px
        for g in range(G):
            visible = inside[g] & ~hidden[g] & (rng.uniform(size=NUM_JOINTS) >= errors.dropout)
            if visible.sum() < errors.min_visible or height[g] < 20:
                continue
            sigma = errors.noise * height[g]
            err = rng.normal(scale=sigma, size=(NUM_JOINTS, 2))
            xy = uv[g] + err
            conf = np.clip(0.95 - 0.5 * np.linalg.norm(err, axis=1) / (3 * sigma) + rng.normal(0, 0.03, NUM_JOINTS),
                           0.3, 1.0)
            outlier = rng.uniform(size=NUM_JOINTS) < errors.outlier_joint_prob
            xy[outlier] += rng.normal(scale=0.25 * height[g], size=(outlier.sum(), 2))
            conf[outlier] = rng.uniform(0.3, 0.7, outlier.sum())
            if rng.uniform() < errors.swap_prob:
                xy, conf, visible = xy[FLIP_PERMUTATION], conf[FLIP_PERMUTATION], visible[FLIP_PERMUTATION]
            kp = np.zeros((NUM_JOINTS, 3))
            kp[visible, :2] = xy[visible]
            kp[visible, 2] = conf[visible]
            kps.append(kp)
            cams.append(v)
            persons.append(g)
        for _ in range(rng.poisson(errors.false_pose_rate)):
            own = [i for i, c in enumerate(cams) if c == v]
            if not own:
                break
            kp = kps[own[rng.integers(len(own))]].copy()
            kp[kp[:, 2] > 0, :2] += rng.uniform([-W / 3, -H / 6], [W / 3, H / 6])
            kp[:, 2] *= rng.uniform(0.3, 0.6)
            kp[(kp[:, 0] < 0) | (kp[:, 0] >= W) | (kp[:, 1] < 0) | (kp[:, 1] >= H)] = 0
            kps.append(kp)
            cams.append(v)
            persons.append(-1)
    keypoints = np.array(kps).reshape(-1, NUM_JOINTS, 3)
    camera = np.array(cams, dtype=int)
    if distortions is not None:
        for v in np.unique(camera):
            rows = camera == v
            present = keypoints[rows, :, 2] > 0
            xy = distort_points(keypoints[rows, :, :2], cameras.K[v], distortions[v])
            keypoints[rows, :, :2] = np.where(present[..., None], xy, 0.0)
    return keypoints, camera, np.array(persons, dtype=int)


def pose_scores(keypoints: np.ndarray) -> np.ndarray:
    """Mean confidence of the present joints. ``(N, 17, 3)`` -> ``(N,)``."""
    present = keypoints[..., 2] > 0
    return np.where(present, keypoints[..., 2], 0).sum(1) / np.maximum(present.sum(1), 1)
