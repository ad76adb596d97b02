"""Synthetic rig captures with ground truth: cameras on a ring, people walking, and 2D
detections with a detector's errors (noise proportional to the person's size, occlusion by
other people, dropped joints, left/right swaps, outlier joints, missed and false detections).
World: metres, z up."""
from __future__ import annotations

import numpy as np

from mvm.core.camera import distort_views, project_views
from mvm.core.config import DEFAULT_FRAME_RATE_HZ
from mvm.core.keypoints import NUM_JOINTS
from mvm.core.scene import Cameras
from mvm.sim.detector import DetectorErrors, detect_people, pose_scores
from mvm.sim.people import STANDING
from mvm.sim.tours import cameras_looking_at

__all__ = ["ring_cameras", "walking_people", "detect_views", "pose_scores", "DetectorErrors"]


def ring_cameras(n: int, radius: float = 4.5, height: float = 2.5, focal: float = 1200.0,
                 size: tuple[int, int] = (1920, 1080), names: tuple[str, ...] | None = None) -> Cameras:
    """``n`` cameras evenly on a circle around the origin, looking at (0, 0, 1)."""
    angle = 2 * np.pi * np.arange(n) / n
    centers = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.full(n, height)], 1)
    return cameras_looking_at(centers, [0.0, 0.0, 1.0], (focal, focal), size,
                              names or tuple(f"cam_{i + 1}" for i in range(n)))


def walking_people(people: int, instants: int, rng: np.random.Generator, area: float = 1.8,
                   speed: float = 1.2, rate: float = DEFAULT_FRAME_RATE_HZ) -> np.ndarray:
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
                 errors: DetectorErrors = DetectorErrors()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulated detections of one instant in every camera (:func:`mvm.sim.detector.detect_people`).

    Args:
        cameras: the cameras, their lenses included.
        poses3d: ``(G, 17, 3)`` true joints, metres (NaN: joint absent in the truth).
    Returns:
        ``keypoints (N, 17, 3)`` (pixels distorted by the cameras' lenses), ``camera (N,)``,
        ``person (N,)`` (-1: a false detection).
    """
    uv, depth = project_views(cameras, np.nan_to_num(poses3d))                    # (V, G, 17, 2), (V, G, 17)
    found = detect_people(uv, depth, cameras.size, cameras.focal, errors, rng,
                          present=np.isfinite(poses3d).all(-1))
    keypoints, camera = found.keypoints, found.view
    xy = distort_views(cameras, keypoints[..., :2], camera)
    keypoints[..., :2] = np.where(keypoints[..., 2:] > 0, xy, 0.0)
    return keypoints, camera, found.person
