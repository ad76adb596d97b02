"""Synthetic mannequin scenes with ground truth: frozen people, a hand-held camera touring
them, and 2D detections with a detector's errors.

World frame: metres, z up, floor at z = 0. The simulated COLMAP model *is* the world, so
estimates compare with the truth directly (no alignment).

Randomness: everything the first version of this simulator drew comes from one generator
seeded with ``seed``, in the same order, so ``SimConfig(people=6, frames=100, seed=s)`` keeps its
scene; the later features (postures, close pairs, look-alikes, merged poses, real
trajectories) draw from a second generator seeded with ``(seed, 1)`` and only when enabled.
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from mvm.core.keypoints import FLIP_PERMUTATION, NUM_JOINTS
from mvm.core.scene import Cameras, Poses2D, Scene

log = logging.getLogger(__name__)

#: Postures a simulated person can take (the pose bank's labels).
POSTURES: tuple[str, ...] = ("standing", "sitting", "crouching")

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
    # --- later additions (defaults leave the scene as the first version made it) ----------
    #: Fractions of standing, sitting and crouching people (the bank's labels); None draws
    #: any pose of the bank.
    postures: tuple[float, float, float] | None = None
    #: Number of people placed side by side with another one, ``close_distance`` apart.
    close_pairs: int = 0
    close_distance: float = 0.45
    #: Bodies of different people keep at least this horizontal distance between joints.
    body_clearance: float = 0.08
    #: Number of people wearing near-identical clothes to another person.
    lookalikes: int = 0
    #: A RealEstate10K / MannequinChallenge camera file: the tour follows its path (resampled
    #: to ``frames``, bent onto the ``arc_deg`` tour and scaled to the room) and its intrinsics.
    trajectory: str | None = None
    seed: int = 0

    @classmethod
    def preset(cls, name: str, **overrides) -> "SimConfig":
        """A detector-error preset ('clean', 'realistic', 'hard') with ``overrides`` applied."""
        if name not in PRESETS:
            raise ValueError(f"unknown preset {name!r}; known: {', '.join(PRESETS)}")
        return dataclasses.replace(cls(), **{**PRESETS[name], **overrides})

    def replace(self, **changes) -> "SimConfig":
        return dataclasses.replace(self, **changes)


#: Detector error presets. 'clean': exact projections (only frame borders and occlusion hide
#: joints); 'realistic': errors of a good bottom-up detector on crowded frames; 'hard':
#: a poor detector, crowded and look-alike people.
PRESETS: dict[str, dict] = {
    "clean": dict(noise=0.0, dropout=0.0, swap_prob=0.0, outlier_joint_prob=0.0, false_pose_rate=0.0,
                  merge_prob=0.0, appearance_noise=0.05, lighting_drift=0.0, shake_deg=0.2),
    "realistic": dict(noise=0.008, dropout=0.03, swap_prob=0.01, outlier_joint_prob=0.01,
                      false_pose_rate=0.1, merge_prob=0.01, appearance_noise=0.15, lighting_drift=0.2,
                      postures=(0.6, 0.3, 0.1), close_pairs=1, lookalikes=1),
    "hard": dict(noise=0.015, dropout=0.08, swap_prob=0.03, outlier_joint_prob=0.03,
                 false_pose_rate=0.5, merge_prob=0.03, appearance_noise=0.3, lighting_drift=0.4,
                 postures=(0.4, 0.4, 0.2), close_pairs=2, lookalikes=2, shake_deg=1.0),
}


@dataclass
class GroundTruth:
    """The truth of a simulated scene.

    Attributes:
        poses3d: ``(G, 17, 3)`` world joints (metres).
        person: ``(N,)`` true person of every 2D pose (-1: a false positive); for a pose that
            merges two people, the person its upper body comes from.
        labels: ``G`` postures ('standing', 'sitting', 'crouching', 'other'; empty if unknown).
        merged_with: ``(N,)`` the second person of a merged pose, -1 otherwise (None: unknown).
    """

    poses3d: np.ndarray
    person: np.ndarray
    labels: tuple[str, ...] = ()
    merged_with: np.ndarray | None = field(default=None)

    def to_json(self) -> dict:
        document = {"format": "mvm.groundtruth/1", "poses3d": np.round(self.poses3d, 6).tolist(),
                    "person_of_annotation": self.person.tolist(), "labels": list(self.labels)}
        if self.merged_with is not None:
            document["merged_with"] = self.merged_with.tolist()
        return document

    @classmethod
    def from_json(cls, data: dict) -> "GroundTruth":
        merged = data.get("merged_with")
        return cls(np.array(data["poses3d"], dtype=float), np.array(data["person_of_annotation"]),
                   tuple(data.get("labels", ())), None if merged is None else np.array(merged))


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


def _intrinsics(config: SimConfig, V: int, focal: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``K: (V, 3, 3)`` and ``size: (V, 2)`` of the simulated camera."""
    fx, fy = focal or (config.focal_px, config.focal_px)
    K = np.array([[fx, 0, config.image_width / 2], [0, fy, config.image_height / 2], [0, 0, 1]])
    size = np.array([config.image_width, config.image_height], dtype=float)
    return np.broadcast_to(K, (V, 3, 3)).copy(), np.broadcast_to(size, (V, 2)).copy()


def _frame_names(V: int) -> tuple[str, ...]:
    return tuple(f"frame_{i:05d}.jpg" for i in range(V))


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
    K, size = _intrinsics(config, V)
    return Cameras(K, R, t, size, _frame_names(V))


def trajectory_tour(config: SimConfig, rng: np.random.Generator, trajectory, target: np.ndarray,
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
    centers += _smooth_noise(rng, V, 3, config.shake_m)
    R = look_at(centers, np.broadcast_to(np.array([target[0], target[1], 1.0]), (V, 3)))
    R = _rotation(_smooth_noise(rng, V, 3, np.radians(config.shake_deg))) @ R
    t = -np.einsum("vij,vj->vi", R, centers)
    fx, fy = np.median(trajectory.intrinsics[:, :2], axis=0) * [config.image_width, config.image_height]
    K, size = _intrinsics(config, V, (float(fx), float(fy)))
    return Cameras(K, R, t, size, _frame_names(V))


def _disc_positions(config: SimConfig, rng: np.random.Generator, extra: np.random.Generator,
                    tangent: np.ndarray) -> np.ndarray:
    """Pelvis positions ``(G, 2)`` in the crowd's disc, ``min_separation`` apart, except that
    the last ``close_pairs`` people each stand ``close_distance`` beside an earlier person
    (side by side as seen from the tour, whose direction along the arc is ``tangent: (2,)``)."""
    G = config.people
    pairs = min(config.close_pairs, G // 2)
    positions: list[np.ndarray] = []
    tries = 0
    while len(positions) < G - pairs:
        tries += 1
        if tries > 20000:
            raise ValueError(f"cannot place {config.people} people {config.min_separation} m apart "
                             f"in a disc of radius {config.crowd_radius} m")
        r = config.crowd_radius * np.sqrt(rng.uniform())
        a = rng.uniform(0, 2 * np.pi)
        p = np.array([r * np.cos(a), r * np.sin(a)])
        if all(np.linalg.norm(p - q) >= config.min_separation for q in positions):
            positions.append(p)
    for k in range(pairs):
        for _ in range(2000):
            anchor = positions[int(extra.integers(G - pairs))]
            turn = extra.normal(0, np.radians(20))
            c, s = np.cos(turn), np.sin(turn)
            direction = np.array([c * tangent[0] - s * tangent[1], s * tangent[0] + c * tangent[1]])
            p = anchor + config.close_distance * direction * extra.choice([-1.0, 1.0])
            if all(np.linalg.norm(p - q) >= 0.95 * config.close_distance for q in positions):
                positions.append(p)
                break
        else:
            raise ValueError(f"cannot place close pair {k + 1}: the crowd is too dense")
    return np.array(positions)


def _choose_postures(config: SimConfig, extra: np.random.Generator, labels: np.ndarray | None) -> list[np.ndarray] | None:
    """For every person, the bank indices it may take its pose from (None: the whole bank)."""
    if config.postures is None or labels is None:
        return None
    mix = np.asarray(config.postures, dtype=float)
    if mix.shape != (3,) or (mix < 0).any() or mix.sum() <= 0:
        raise ValueError(f"postures: expected 3 non-negative fractions, got {config.postures}")
    pools = [np.flatnonzero(labels == name) for name in POSTURES]
    available = np.array([len(pool) > 0 for pool in pools])
    if not (mix * available).any():
        raise ValueError(f"the pose bank has none of the postures {POSTURES} asked for")
    if not available.all():
        log.warning("the pose bank lacks %s poses; using the other postures",
                    ", ".join(np.array(POSTURES)[~available]))
    mix = mix * available
    chosen = extra.choice(3, size=config.people, p=mix / mix.sum())
    return [pools[c] for c in chosen]


def place_people(config: SimConfig, rng: np.random.Generator, bank_poses: np.ndarray,
                 toward: np.ndarray, bank_labels: np.ndarray | None = None,
                 extra: np.random.Generator | None = None) -> tuple[np.ndarray, tuple[str, ...]]:
    """Place ``config.people`` bank poses on the floor, apart, facing roughly ``toward: (2,)``.

    ``bank_poses: (B, 17, 3)`` in the bank frame (pelvis at xy = 0, feet at z = 0, facing +y),
    ``bank_labels: (B,)`` their postures -> ``(G, 17, 3)`` world poses and their ``G`` labels.
    Bodies keep ``body_clearance`` apart: a person that would touch another is turned.
    """
    extra = np.random.default_rng([config.seed, 1]) if extra is None else extra
    heading = np.arctan2(toward[1], toward[0])
    tangent = np.array([-np.sin(heading), np.cos(heading)])
    positions = _disc_positions(config, rng, extra, tangent)
    pools = _choose_postures(config, extra, bank_labels)
    poses, labels = [], []
    for g, p in enumerate(positions):
        index = rng.integers(len(bank_poses))
        if pools is not None:
            index = pools[g][extra.integers(len(pools[g]))]
        pose = bank_poses[index] * rng.uniform(*config.size_range)
        facing = np.arctan2(*(toward - p)[::-1]) - np.pi / 2 + rng.normal(0, np.radians(40))
        for attempt in range(50):
            c, s = np.cos(facing), np.sin(facing)
            Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
            placed = pose @ Rz.T + np.array([p[0], p[1], 0.0])
            if not poses or _clearance(placed, np.array(poses)) >= config.body_clearance:
                break
            facing = extra.uniform(0, 2 * np.pi)
        else:
            log.debug("person %d touches a neighbour after 50 turns", g)
        poses.append(placed)
        labels.append(str(bank_labels[index]) if bank_labels is not None else "")
    return np.array(poses), tuple(labels) if bank_labels is not None else ()


def _clearance(pose: np.ndarray, others: np.ndarray) -> float:
    """Smallest horizontal distance between a joint of ``pose: (17, 3)`` and one of
    ``others: (G, 17, 3)`` at overlapping heights (within 0.3 m)."""
    d = np.linalg.norm(pose[None, :, None, :2] - others[:, None, :, :2], axis=-1)       # (G, 17, 17)
    level = np.abs(pose[None, :, None, 2] - others[:, None, :, 2]) < 0.3
    return float(np.where(level, d, np.inf).min())


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


def project_people(cameras: Cameras, poses3d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact projections of ``poses3d: (G, 17, 3)`` in every view: ``uv: (V, G, 17, 2)`` px
    and camera depths ``(V, G, 17)``."""
    G = len(poses3d)
    homogeneous = np.concatenate([poses3d, np.ones((G, NUM_JOINTS, 1))], axis=2)
    x = np.einsum("vab,gjb->vgja", cameras.P, homogeneous)
    depth = x[..., 2]
    return x[..., :2] / depth[..., None], depth


def _image_size_of_people(uv: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Larger side of the box of the in-frame joints. ``uv: (G, 17, 2)``, ``inside: (G, 17)``
    -> ``(G,)`` px (0 for a person with no joint in the frame)."""
    hi = np.where(inside[..., None], uv, -np.inf).max(axis=1)
    lo = np.where(inside[..., None], uv, np.inf).min(axis=1)
    return np.where(inside.any(axis=1), (hi - lo).max(axis=1), 0.0)


#: Joints a merged pose takes from its second person (the lower body).
_LOWER_BODY = np.arange(11, 17)


def _merge_in_view(lists: dict[str, list], start: int, probability: float,
                   extra: np.random.Generator) -> None:
    """Merge overlapping detections of one view, in place: with ``probability`` per pair of
    people whose boxes overlap (IoU > 0.2), one keeps its upper body and takes the other's
    lower body; the other's detection is removed. ``lists`` holds the aligned per-detection
    lists (keypoints, person, merged_with, …); the view's detections start at ``start``."""
    keypoints, person, merged_with = lists["keypoints"], lists["person"], lists["merged_with"]
    index = list(range(start, len(keypoints)))
    if len(index) < 2 or probability <= 0:
        return
    kp = np.array([keypoints[i] for i in index])
    present = kp[:, :, 2] > 0
    lo = np.array([k[p, :2].min(0) for k, p in zip(kp, present)])
    hi = np.array([k[p, :2].max(0) for k, p in zip(kp, present)])
    overlap = np.prod(np.clip(np.minimum(hi[:, None], hi[None]) - np.maximum(lo[:, None], lo[None]), 0, None), axis=-1)
    area = np.prod(hi - lo, axis=-1)
    iou = overlap / np.maximum(area[:, None] + area[None] - overlap, 1e-9)
    removed: set[int] = set()
    for a, b in zip(*np.nonzero(np.triu(iou > 0.2, 1))):
        if a in removed or b in removed or extra.uniform() >= probability:
            continue
        upper, lower = (a, b) if extra.uniform() < 0.5 else (b, a)
        keypoints[index[upper]][_LOWER_BODY] = keypoints[index[lower]][_LOWER_BODY]
        merged_with[index[upper]] = person[index[lower]]
        removed.add(lower)
    for r in sorted(removed, reverse=True):
        for seq in lists.values():
            del seq[index[r]]


def detect(config: SimConfig, rng: np.random.Generator, cameras: Cameras, poses3d: np.ndarray,
           appearance_base: np.ndarray, extra: np.random.Generator | None = None
           ) -> tuple[Poses2D, np.ndarray, np.ndarray]:
    """Simulated 2D detections in every view: ``(Poses2D, true person (N,), merged_with (N,))``.

    Per person and view: joints outside the frame or behind another person (depth-ordered,
    :func:`occluded_joints`) are lost; the others get Gaussian noise of ``noise`` times the
    person's image height, random ``dropout``, gross outliers, a left-right swap; confidences
    fall with the error. Then pairs of overlapping people may merge into one pose
    (``merge_prob``) and false positives are added (``false_pose_rate`` per view).
    """
    extra = np.random.default_rng([config.seed, 1]) if extra is None else extra
    G = len(poses3d)
    W, H = config.image_width, config.image_height
    keypoints, views, person, merged_with, apps = [], [], [], [], []
    drift = 1.0 + config.lighting_drift * np.linspace(-0.5, 0.5, len(cameras))
    uv_all, depth_all = project_people(cameras, poses3d)
    for v in range(len(cameras)):
        uv, depth = uv_all[v], depth_all[v]
        inside = (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H) & (depth > 0.1)
        hidden = occluded_joints(uv, depth, cameras.focal[v]) if config.occlusion else np.zeros_like(inside)
        scale = _image_size_of_people(uv, inside)                                           # (G,)
        start = len(keypoints)
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
            merged_with.append(-1)
            apps.append(appearance_base[g] * drift[v] + rng.normal(0, config.appearance_noise, appearance_base.shape[1]))
        if config.merge_prob > 0:
            _merge_in_view(dict(keypoints=keypoints, views=views, person=person, merged_with=merged_with,
                                apps=apps), start, config.merge_prob, extra)
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
            merged_with.append(-1)
            apps.append(rng.uniform(0, 1, appearance_base.shape[1]))
    N = len(keypoints)
    kp = np.array(keypoints).reshape(N, NUM_JOINTS, 3)
    present = kp[:, :, 2] > 0
    score = np.where(present, kp[:, :, 2], 0).sum(1) / np.maximum(present.sum(1), 1)
    appearance = np.clip(np.array(apps).reshape(N, -1), 0, None) if config.appearance_dim else None
    poses = Poses2D(kp, np.array(views, dtype=int), np.arange(1, N + 1), score, appearance)
    return poses, np.array(person, dtype=int), np.array(merged_with, dtype=int)


def _appearance_base(config: SimConfig, rng: np.random.Generator, extra: np.random.Generator) -> np.ndarray:
    """Clothes of every person ``(G, D)``: random colours, with ``lookalikes`` people copying
    another's clothes up to a small difference, or all alike with ``identical_clothes``."""
    dim = max(config.appearance_dim, 1)
    base = rng.uniform(0, 1, (config.people, dim))
    if config.identical_clothes:
        base[:] = base[0]
    elif config.lookalikes and config.people > 1:
        for g in range(1, min(config.lookalikes, config.people - 1) + 1):
            twin = config.people - g
            base[twin] = np.clip(base[int(extra.integers(twin))] + extra.normal(0, 0.03, dim), 0, 1)
    return base


def simulate(config: SimConfig | None = None, bank_poses: np.ndarray | None = None,
             bank_labels: np.ndarray | None = None) -> tuple[Scene, GroundTruth]:
    """Simulate a mannequin scene: ``(Scene, GroundTruth)``.

    Poses come from the shipped pose bank (complete poses, with their posture labels) unless
    ``bank_poses: (B, 17, 3)`` (bank frame) and optionally ``bank_labels: (B,)`` are given.
    """
    config = config or SimConfig()
    if config.people < 1 or config.frames < 2:
        raise ValueError(f"expected people >= 1 and frames >= 2, got {config.people} and {config.frames}")
    rng = np.random.default_rng(config.seed)
    extra = np.random.default_rng([config.seed, 1])
    if bank_poses is None:
        from mvm.core.posebank import load_pose_bank

        bank = load_pose_bank()
        bank = bank.subset(bank.complete)
        bank_poses, bank_labels = bank.poses, bank.labels
    heading = rng.uniform(0, 2 * np.pi)
    toward = 10 * np.array([np.cos(heading), np.sin(heading)])
    labels = None if bank_labels is None else np.asarray(bank_labels).astype(str)
    poses3d, posture = place_people(config, rng, np.asarray(bank_poses, dtype=float), toward, labels, extra)
    target = np.array([0.0, 0.0, 1.0])
    if config.trajectory:
        from mvm.io.trajectory import read_trajectory

        cams = trajectory_tour(config, rng, read_trajectory(config.trajectory), target, heading)
    else:
        cams = camera_tour(config, rng, target, heading)
    base = _appearance_base(config, rng, extra)
    poses2d, person, merged_with = detect(config, rng, cams, poses3d, base, extra)
    if not config.appearance_dim:
        poses2d = Poses2D(poses2d.keypoints, poses2d.view, poses2d.ids, poses2d.score, None)
    scene = Scene("simulated", cams, poses2d)
    return scene, GroundTruth(poses3d, person, posture, merged_with)


def write_simulation(path: str | Path, scene: Scene, truth: GroundTruth, config: SimConfig | None = None) -> Path:
    """Write the scene directory ``path`` and the ground truth beside it,
    ``<path>.groundtruth.json`` (outside the scene directory). Returns the truth's path."""
    from mvm.io.files import atomic_write_json
    from mvm.io.scene_dir import write_scene

    path = Path(path)
    write_scene(path, scene.cameras, scene.poses)
    document = truth.to_json()
    if config is not None:
        document["simulation"] = asdict(config)
    truth_path = path.parent / f"{path.name}.groundtruth.json"
    atomic_write_json(truth_path, document)
    return truth_path


def read_ground_truth(path: str | Path) -> GroundTruth:
    """Read ``<scene>.groundtruth.json`` as written by :func:`write_simulation`."""
    from mvm.errors import InputError
    from mvm.io.checks import load_json_object

    path = Path(path)
    data = load_json_object(path, what="a ground truth object")
    for key in ("poses3d", "person_of_annotation"):
        if key not in data:
            raise InputError(path, key, "missing")
    truth = GroundTruth.from_json(data)
    if truth.poses3d.ndim != 3 or truth.poses3d.shape[1:] != (NUM_JOINTS, 3):
        raise InputError(path, "poses3d", f"expected (G, 17, 3), got {truth.poses3d.shape}")
    return truth
