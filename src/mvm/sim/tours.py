"""Camera tours of a simulated scene: a hand-held arc around the crowd, or a real camera path
bent onto that arc. World frame: metres, z up; cameras look along their +z axis, y down."""
from __future__ import annotations

import numpy as np

from mvm.core.scene import Cameras


def look_at(centers: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """World->camera rotations looking from ``centers: (V, 3)`` at ``targets: (V, 3)`` with
    the world z up: ``(V, 3, 3)`` (rows: camera x right, y down, z forward)."""
    forward = targets - centers
    forward /= np.linalg.norm(forward, axis=1, keepdims=True)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    down = np.cross(forward, right)
    return np.stack([right, down, forward], axis=1)


def _rotation(axis_angle: np.ndarray) -> np.ndarray:
    """Rodrigues. ``axis_angle: (V, 3)`` radians -> ``(V, 3, 3)``."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(axis_angle).as_matrix()


def _smooth_noise(rng, n: int, dims: int, scale: float, smoothness: int = 8) -> np.ndarray:
    """Low-pass random walk ``(n, dims)`` with standard deviation about ``scale``."""
    raw = rng.normal(size=(n + 2 * smoothness, dims))
    kernel = np.hanning(2 * smoothness + 1)
    kernel /= np.sqrt((kernel**2).sum())
    smooth = np.stack([np.convolve(raw[:, d], kernel, mode="same") for d in range(dims)], axis=1)
    return scale * smooth[smoothness:smoothness + n]


def cameras_looking_at(centers: np.ndarray, target: np.ndarray, focal: tuple[float, float],
                       size: tuple[float, float], names: tuple[str, ...] | None = None,
                       shake: np.ndarray | None = None) -> Cameras:
    """Pinhole cameras at ``centers: (V, 3)`` looking at ``target: (3,)`` (z up), focal
    lengths ``(fx, fy)`` px, principal point at the centre of the ``(width, height)`` image,
    rotated further by ``shake: (V, 3, 3)`` when given; frames named ``frame_00000.jpg``…
    unless ``names``."""
    V = len(centers)
    R = look_at(centers, np.broadcast_to(np.asarray(target, dtype=float), (V, 3)))
    if shake is not None:
        R = shake @ R
    t = -np.einsum("vij,vj->vi", R, centers)
    fx, fy = focal
    K = np.array([[fx, 0, size[0] / 2], [0, fy, size[1] / 2], [0, 0, 1]])
    sizes = np.array([size[0], size[1]], dtype=float)
    names = names or tuple(f"frame_{i:05d}.jpg" for i in range(V))
    return Cameras(np.broadcast_to(K, (V, 3, 3)).copy(), R, t, np.broadcast_to(sizes, (V, 2)).copy(), names)


def _shaken_cameras(config, rng: np.random.Generator, centers: np.ndarray, target: np.ndarray,
                    focal: tuple[float, float] | None = None) -> Cameras:
    """Cameras at ``centers: (V, 3)`` (before the positional shake) looking 1 m above the
    floor at ``target: (3,)``, with the hand-held shake of ``config``."""
    V = len(centers)
    centers = centers + _smooth_noise(rng, V, 3, config.shake_m)
    shake = _rotation(_smooth_noise(rng, V, 3, np.radians(config.shake_deg)))
    return cameras_looking_at(centers, [target[0], target[1], 1.0], focal or (config.focal_px, config.focal_px),
                              (config.image_width, config.image_height), shake=shake)


def camera_tour(config, rng: np.random.Generator, target: np.ndarray, heading: float) -> Cameras:
    """A hand-held arc around ``target: (3,)`` centred on the direction ``heading`` (radians,
    from the target): ``config.frames`` views with shake (``config``: a ``SimConfig``)."""
    V = config.frames
    angles = heading + np.radians(config.arc_deg) * np.linspace(-0.5, 0.5, V)
    centers = np.stack([target[0] + config.camera_distance * np.cos(angles),
                        target[1] + config.camera_distance * np.sin(angles),
                        np.full(V, config.camera_height)], axis=1)
    return _shaken_cameras(config, rng, centers, target)


def trajectory_tour(config, rng: np.random.Generator, trajectory, target: np.ndarray,
                    heading: float) -> Cameras:
    """A tour that follows a real camera path (``mvm.io.trajectory.Trajectory``).

    The path's centres are resampled in time to ``config.frames`` (cubic spline over the
    timestamps) and expressed in their principal axes: the main direction of travel becomes
    the angle along the ``arc_deg`` tour around ``target: (3,)`` (so the speed profile is the
    real one and the parallax is controlled), the second axis a change of distance and the
    third a change of height, both scaled like the first (clipped to half the distance). The
    camera looks at the crowd, with the hand-held shake of ``config``; the focal lengths are the
    file's (normalised by the image size).
    """
    from scipy.interpolate import CubicSpline

    V = config.frames
    time = trajectory.timestamps_us - trajectory.timestamps_us[0]
    samples = np.linspace(0.0, time[-1], V)
    path = CubicSpline(time, trajectory.centers, axis=0)(samples)               # (V, 3)
    path -= path.mean(axis=0)
    _, _, axes = np.linalg.svd(path, full_matrices=False)
    local = path @ axes.T                                                        # (V, 3) principal coords
    along = local[:, 0] if local[-1, 0] >= local[0, 0] else -local[:, 0]
    extent = max(float(np.ptp(along)), 1e-9)
    arc = np.radians(config.arc_deg)
    metres_per_unit = arc * config.camera_distance / extent
    angles = heading + arc * ((along - along.min()) / extent - 0.5)
    limit = 0.5 * config.camera_distance
    radius = config.camera_distance + np.clip(metres_per_unit * local[:, 1], -limit, limit)
    height = config.camera_height + np.clip(metres_per_unit * local[:, 2], -0.5, 0.5)
    centers = np.stack([target[0] + radius * np.cos(angles), target[1] + radius * np.sin(angles), height], axis=1)
    fx, fy = np.median(trajectory.intrinsics[:, :2], axis=0) * [config.image_width, config.image_height]
    return _shaken_cameras(config, rng, centers, target, (float(fx), float(fy)))
