"""Synthetic mannequin scenes with ground truth: frozen people, a hand-held camera touring
them, and 2D detections with a detector's errors.

World frame: metres, z up, floor at z = 0. The simulated COLMAP model *is* the world, so
estimates compare with the truth directly (no alignment).
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .keypoints import FLIP_PERMUTATION, NUM_JOINTS
from .scene import Cameras, Poses2D, Scene

#: Limbs used as occluders (joint pairs), with the torso as two diagonals.
_OCCLUDER_LIMBS = np.array([(5, 7), (7, 9), (6, 8), (8, 10), (11, 13), (13, 15), (12, 14), (14, 16),
                            (5, 12), (6, 11), (5, 6), (11, 12), (0, 5), (0, 6)])


@dataclass(frozen=True)
class SimConfig:
    """A simulated scene. Lengths in metres, angles in degrees, noise as a fraction of the
    person's image height."""

    people: int = 6
    frames: int = 100
    image_width: int = 1280
    image_height: int = 720
    focal_px: float = 1000.0
    #: Total angle of the camera's tour around the crowd.
    arc_deg: float = 60.0
    #: Distance of the camera path from the crowd's centre.
    camera_distance: float = 5.0
    camera_height: float = 1.6
    #: Hand-held shake: rotation (deg) and position (m) jitter, and a vertical bob (m).
    shake_deg: float = 0.5
    shake_m: float = 0.02
    #: People stand in a disc of this radius, at least ``min_separation`` apart (pelvis).
    crowd_radius: float = 2.0
    min_separation: float = 0.7
    #: Body size factor range applied to the bank's poses.
    size_range: tuple[float, float] = (0.85, 1.1)
    # --- detector errors ------------------------------------------------------------------
    noise: float = 0.008
    dropout: float = 0.03
    occlusion: bool = True
    swap_prob: float = 0.01
    outlier_joint_prob: float = 0.01
    false_pose_rate: float = 0.1
    merge_prob: float = 0.0
    # --- appearance -----------------------------------------------------------------------
    appearance_dim: int = 16
    appearance_noise: float = 0.15
    #: Multiplicative lighting drift over the tour (fraction).
    lighting_drift: float = 0.2
    #: Persons share the same clothes (appearance is useless).
    identical_clothes: bool = False
    seed: int = 0


@dataclass
class GroundTruth:
    """``poses3d: (G, 17, 3)`` world joints; ``person: (N,)`` true person of every 2D pose
    (-1: a false positive); ``centers: (V, 3)`` camera centres."""

    poses3d: np.ndarray
    person: np.ndarray
    labels: tuple[str, ...] = ()

    def to_json(self) -> dict:
        return {"format": "mvm.groundtruth/1", "poses3d": np.round(self.poses3d, 6).tolist(),
                "person_of_annotation": self.person.tolist(), "labels": list(self.labels)}

    @classmethod
    def from_json(cls, data: dict) -> "GroundTruth":
        return cls(np.array(data["poses3d"], dtype=float), np.array(data["person_of_annotation"]),
                   tuple(data.get("labels", ())))


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


def camera_tour(config: SimConfig, rng: np.random.Generator, target: np.ndarray, heading: float) -> Cameras:
    """A hand-held arc around ``target: (3,)`` centred on the direction ``heading`` (radians,
    from the target): ``config.frames`` views with shake."""
    V = config.frames
    angles = heading + np.radians(config.arc_deg) * np.linspace(-0.5, 0.5, V)
    centers = np.stack([target[0] + config.camera_distance * np.cos(angles),
                        target[1] + config.camera_distance * np.sin(angles),
                        np.full(V, config.camera_height)], axis=1)
    centers += _smooth_noise(rng, V, 3, config.shake_m)
    look = np.broadcast_to(np.array([target[0], target[1], 1.0]), (V, 3))
    R = look_at(centers, look)
    R = _rotation(_smooth_noise(rng, V, 3, np.radians(config.shake_deg))) @ R
    t = -np.einsum("vij,vj->vi", R, centers)
    K = np.array([[config.focal_px, 0, config.image_width / 2],
                  [0, config.focal_px, config.image_height / 2], [0, 0, 1]])
    size = np.array([config.image_width, config.image_height], dtype=float)
    names = tuple(f"frame_{i:05d}.jpg" for i in range(V))
    return Cameras(np.broadcast_to(K, (V, 3, 3)).copy(), R, t, np.broadcast_to(size, (V, 2)).copy(), names)


def place_people(config: SimConfig, rng: np.random.Generator, bank_poses: np.ndarray,
                 toward: np.ndarray) -> np.ndarray:
    """Place ``config.people`` bank poses on the floor, apart, facing roughly ``toward: (2,)``.
    ``bank_poses: (B, 17, 3)`` in the bank frame (pelvis at xy = 0, feet at z = 0, facing +y)
    -> ``(G, 17, 3)``."""
    positions: list[np.ndarray] = []
    tries = 0
    while len(positions) < config.people:
        tries += 1
        if tries > 20000:
            raise ValueError(f"cannot place {config.people} people {config.min_separation} m apart "
                             f"in a disc of radius {config.crowd_radius} m")
        r = config.crowd_radius * np.sqrt(rng.uniform())
        a = rng.uniform(0, 2 * np.pi)
        p = np.array([r * np.cos(a), r * np.sin(a)])
        if all(np.linalg.norm(p - q) >= config.min_separation for q in positions):
            positions.append(p)
    poses = []
    for p in positions:
        pose = bank_poses[rng.integers(len(bank_poses))] * rng.uniform(*config.size_range)
        facing = np.arctan2(*(toward - p)[::-1]) - np.pi / 2 + rng.normal(0, np.radians(40))
        c, s = np.cos(facing), np.sin(facing)
        Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        poses.append(pose @ Rz.T + np.array([p[0], p[1], 0.0]))
    return np.array(poses)


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of ``points: (..., 2)`` to segments ``a, b: (..., 2)`` (broadcast)."""
    ab = b - a
    t = np.clip(((points - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0, 1)
    return np.linalg.norm(points - (a + t[..., None] * ab), axis=-1)


def occluded_joints(uv: np.ndarray, depth: np.ndarray, focal: float, limb_radius: float = 0.07) -> np.ndarray:
    """Which joints are hidden behind another person in one view.

    ``uv: (G, 17, 2)`` pixels, ``depth: (G, 17)`` camera z -> ``(G, 17)`` bool: a joint is
    hidden when it lies within ``limb_radius`` (metres, at the occluder's depth) of a limb of a
    person whose limb is nearer the camera than the joint by more than 0.15 m.
    """
    G = len(uv)
    limbs_a = uv[:, _OCCLUDER_LIMBS[:, 0]]                               # (G, L, 2)
    limbs_b = uv[:, _OCCLUDER_LIMBS[:, 1]]
    limb_depth = 0.5 * (depth[:, _OCCLUDER_LIMBS[:, 0]] + depth[:, _OCCLUDER_LIMBS[:, 1]])
    radius = focal * limb_radius / np.maximum(limb_depth, 1e-3)          # (G, L) px
    dist = _segment_distance(uv[:, :, None, None, :], limbs_a[None, None], limbs_b[None, None])  # (G, J, G, L)
    nearer = limb_depth[None, None] < depth[:, :, None, None] - 0.15
    hidden = (dist < radius[None, None]) & nearer
    hidden[np.arange(G), :, np.arange(G)] = False
    return hidden.any(axis=(2, 3))


def detect(config: SimConfig, rng: np.random.Generator, cameras: Cameras, poses3d: np.ndarray,
           appearance_base: np.ndarray) -> tuple[Poses2D, np.ndarray]:
    """Simulated 2D detections in every view: ``(Poses2D, true person (N,))``."""
    G = len(poses3d)
    W, H = config.image_width, config.image_height
    keypoints, views, person, apps = [], [], [], []
    drift = 1.0 + config.lighting_drift * np.linspace(-0.5, 0.5, len(cameras))
    for v in range(len(cameras)):
        cam = cameras.P[v]
        homogeneous = np.concatenate([poses3d, np.ones((G, NUM_JOINTS, 1))], axis=2)
        x = homogeneous @ cam.T
        depth = x[..., 2]
        uv = x[..., :2] / depth[..., None]
        inside = (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H) & (depth > 0.1)
        hidden = occluded_joints(uv, depth, config.focal_px) if config.occlusion else np.zeros_like(inside)
        height = np.ptp(np.where(inside[..., None], uv, np.nan), axis=1)
        scale = np.nan_to_num(np.nanmax(height, axis=1), nan=0.0)                                # (G,)
        for g in range(G):
            visible = inside[g] & ~hidden[g] & (rng.uniform(size=NUM_JOINTS) >= config.dropout)
            if visible.sum() < 5 or scale[g] < 20:
                continue
            sigma = config.noise * scale[g]
            err = rng.normal(scale=sigma, size=(NUM_JOINTS, 2))
            xy = uv[g] + err
            conf = np.clip(0.95 - 0.5 * np.linalg.norm(err, axis=1) / max(3 * sigma, 1e-9)
                           + rng.normal(0, 0.03, NUM_JOINTS), 0.3, 1.0)
            outlier = rng.uniform(size=NUM_JOINTS) < config.outlier_joint_prob
            xy[outlier] += rng.normal(scale=0.25 * scale[g], size=(outlier.sum(), 2))
            conf[outlier] = rng.uniform(0.3, 0.7, outlier.sum())
            if rng.uniform() < config.swap_prob:
                xy, conf = xy[FLIP_PERMUTATION], conf[FLIP_PERMUTATION]
                visible = visible[FLIP_PERMUTATION]
            kp = np.zeros((NUM_JOINTS, 3))
            kp[visible, :2] = xy[visible]
            kp[visible, 2] = conf[visible]
            keypoints.append(kp)
            views.append(v)
            person.append(g)
            apps.append(appearance_base[g] * drift[v] + rng.normal(0, config.appearance_noise, appearance_base.shape[1]))
        n_false = rng.poisson(config.false_pose_rate)
        for _ in range(n_false):
            if not keypoints:
                break
            kp = keypoints[rng.integers(len(keypoints))].copy()
            shift = rng.uniform([-W / 3, -H / 6], [W / 3, H / 6])
            kp[kp[:, 2] > 0, :2] += shift
            kp[:, 2] *= rng.uniform(0.3, 0.6)
            kp[(kp[:, 0] < 0) | (kp[:, 0] >= W) | (kp[:, 1] < 0) | (kp[:, 1] >= H)] = 0
            keypoints.append(kp)
            views.append(v)
            person.append(-1)
            apps.append(rng.uniform(0, 1, appearance_base.shape[1]))
    N = len(keypoints)
    kp = np.array(keypoints).reshape(N, NUM_JOINTS, 3)
    present = kp[:, :, 2] > 0
    score = np.where(present, kp[:, :, 2], 0).sum(1) / np.maximum(present.sum(1), 1)
    appearance = np.clip(np.array(apps).reshape(N, -1), 0, None) if config.appearance_dim else None
    return Poses2D(kp, np.array(views), np.arange(1, N + 1), score, appearance), np.array(person)


def simulate(config: SimConfig | None = None, bank_poses: np.ndarray | None = None) -> tuple[Scene, GroundTruth]:
    """Simulate a mannequin scene: ``(Scene, GroundTruth)``. Poses come from the shipped pose
    bank unless ``bank_poses: (B, 17, 3)`` (bank frame) is given."""
    config = config or SimConfig()
    rng = np.random.default_rng(config.seed)
    if bank_poses is None:
        from .posebank import load_pose_bank

        bank = load_pose_bank()
        bank_poses = bank.poses
    heading = rng.uniform(0, 2 * np.pi)
    toward = 10 * np.array([np.cos(heading), np.sin(heading)])
    poses3d = place_people(config, rng, np.asarray(bank_poses, dtype=float), toward)
    cams = camera_tour(config, rng, np.array([0.0, 0.0, 1.0]), heading)
    dim = max(config.appearance_dim, 1)
    base = rng.uniform(0, 1, (config.people, dim))
    if config.identical_clothes:
        base[:] = base[0]
    poses2d, person = detect(config, rng, cams, poses3d, base)
    if not config.appearance_dim:
        poses2d = Poses2D(poses2d.keypoints, poses2d.view, poses2d.ids, poses2d.score, None)
    scene = Scene("simulated", cams, poses2d)
    return scene, GroundTruth(poses3d, person)


def write_simulation(path: str | Path, scene: Scene, truth: GroundTruth, config: SimConfig | None = None) -> Path:
    """Write the scene directory ``path`` and the ground truth beside it,
    ``<path>.groundtruth.json`` (outside the scene directory). Returns the truth's path."""
    from .io.files import atomic_write_json
    from .io.scene_dir import write_scene

    path = Path(path)
    write_scene(path, scene.cameras, scene.poses)
    document = truth.to_json()
    if config is not None:
        document["simulation"] = asdict(config)
    truth_path = path.parent / f"{path.name}.groundtruth.json"
    atomic_write_json(truth_path, document)
    return truth_path


def read_ground_truth(path: str | Path) -> GroundTruth:
    return GroundTruth.from_json(json.loads(Path(path).read_text()))
