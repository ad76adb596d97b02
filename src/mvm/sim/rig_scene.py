"""A simulated rig capture: cameras on a ring around people moving with real motion, each
camera's 2D detections (the detector's errors of :mod:`mvm.sim.detector`) and, optionally,
per-camera frame offsets (unsynchronized videos). No I/O (:mod:`mvm.io.rig_simulation` writes
the rig folder). World: metres, z up.

Frame offsets: camera ``c``'s frame ``f`` shows the scene's instant ``f + offsets[c]``. The
number of frames to *add* to camera ``c``'s frame numbers to reach the reference camera's
(``sync.toml``, :mod:`mvm.rig.synchronize`) is then ``offsets[c] - offsets[0]``.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from mvm.core.config import DEFAULT_FRAME_RATE_HZ, check_settings, setting
from mvm.core.keypoints import INDEX, NUM_JOINTS
from mvm.core.posebank import load_pose_bank
from mvm.io.calib_toml import RigCalibration
from mvm.sim.detector import DetectorErrors, pose_scores
from mvm.sim.rig import detect_views, ring_cameras

#: The capture rate of the CMU motions of the pose bank (their frame numbers). [Hz]
BANK_RATE_HZ = 120.0
#: A bank motion is cut where two consecutive samples are further apart than this (source frames,
#: metres of mean joint distance).
MAX_SAMPLE_GAP_FRAMES = 60
MAX_SAMPLE_JUMP_M = 0.15
#: People turn around over this long when they reach the edge of their area. [s]
TURN_S = 0.5
#: Fewest bank poses a motion needs to be played (its samples are a few source frames apart).
MIN_MOTION_POSES = 40


@dataclass(frozen=True)
class RigSimConfig:
    """The settings of a simulated rig capture."""

    #: Cameras on a ring around the people. [cameras]
    cameras: int = setting(5, ge=1, le=30)
    #: People walking about. [persons]
    people: int = setting(3, ge=1, le=30)
    #: Frames each camera records. [frames]
    frames: int = setting(120, ge=2, le=100_000)
    #: Frame offset of every camera (``cameras`` numbers, see the module docstring); empty: 0. [frames]
    offsets: tuple[int, ...] = ()
    #: Frame rate of every camera. [Hz]
    frame_rate: float = setting(DEFAULT_FRAME_RATE_HZ, gt=0)
    #: Radius of the camera ring. [m]
    radius: float = setting(4.5, gt=0)
    #: Height of the cameras above the floor. [m]
    height: float = setting(2.5, gt=0)
    #: People stay in a square of this half-side around the ring's centre. [m]
    area: float = setting(1.5, gt=0)
    #: Largest walking speed; each person draws one in [0, speed]. [m/s]
    speed: float = setting(0.8, ge=0)
    #: Size of the cameras' images. [px]
    image_width: int = setting(1920, ge=16, le=16384)
    image_height: int = setting(1080, ge=16, le=16384)
    #: Focal length of the cameras. [px]
    focal_px: float = setting(1200.0, gt=0)
    #: Radial lens distortion k1 of the cameras (each camera a different fraction of it). [1]
    distortion: float = setting(-0.05, ge=-1, le=1)
    #: The detector's errors (:class:`mvm.sim.detector.DetectorErrors`). [-]
    errors: DetectorErrors = field(default_factory=DetectorErrors)
    #: Random seed of the simulation. [1]
    seed: int = setting(0, ge=0)

    def __post_init__(self):
        check_settings(self)
        if self.offsets and len(self.offsets) != self.cameras:
            raise ValueError(f"offsets: expected {self.cameras} numbers (one per camera), got {len(self.offsets)}")
        if self.offsets and max(abs(int(o)) for o in self.offsets) >= self.frames:
            raise ValueError(f"offsets: each must be shorter than the {self.frames} frames, got {list(self.offsets)}")

    def camera_offsets(self) -> np.ndarray:
        """``(V,)`` int frame offsets."""
        return np.array(self.offsets if self.offsets else [0] * self.cameras, dtype=int)


@dataclass
class RigSimulation:
    """A simulated rig capture.

    Attributes:
        calibration: the true cameras (with their lens distortion).
        offsets: ``(V,)`` frame offsets (camera ``c``'s frame ``f`` shows instant ``f + offsets[c]``).
        instants: ``(S,)`` the scene's instants, increasing by 1.
        poses3d: ``(S, G, 17, 3)`` true joints at every instant (metres).
        keypoints: ``(N, 17, 3)`` detected 2D poses, *distorted* pixels (as a detector sees them).
        camera: ``(N,)`` camera of every pose; frame: ``(N,)`` its frame number in that camera;
        person: ``(N,)`` true person (-1: a false pose); score: ``(N,)`` the pose's confidence.
        frames: frames recorded by every camera (``0 .. frames - 1``).
        frame_rate: Hz.
    """

    calibration: RigCalibration
    offsets: np.ndarray
    instants: np.ndarray
    poses3d: np.ndarray
    keypoints: np.ndarray
    camera: np.ndarray
    frame: np.ndarray
    person: np.ndarray
    score: np.ndarray
    frames: int
    frame_rate: float

    @property
    def sync_offsets(self) -> np.ndarray:
        """``(V,)`` frames to add to each camera's frame numbers to reach the first camera's."""
        return self.offsets - self.offsets[0]


def bank_motions(min_poses: int = MIN_MOTION_POSES) -> list[tuple[np.ndarray, np.ndarray]]:
    """The CMU motions of the shipped pose bank: ``[(source frames (M,) increasing, poses (M, 17, 3))]``
    in the bank frame (pelvis over the origin, facing +y, ankles on the floor)."""
    bank = load_pose_bank()
    keep = bank.complete & ~np.char.startswith(bank.sources.astype(str), "panoptic")
    motion = np.array([s.split(":")[0] for s in bank.sources[keep]])
    frame = np.array([int(s.split(":")[1]) for s in bank.sources[keep]])
    poses = bank.poses[keep].astype(float)
    out = []
    for name in np.unique(motion):
        rows = np.flatnonzero(motion == name)
        order = rows[np.argsort(frame[rows])]
        # cut the motion where its samples are far apart in time or in pose; keep its longest part
        gap = np.diff(frame[order]) > MAX_SAMPLE_GAP_FRAMES
        jump = np.linalg.norm(np.diff(poses[order], axis=0), axis=-1).mean(-1) > MAX_SAMPLE_JUMP_M
        parts = np.split(order, np.flatnonzero(gap | jump) + 1)
        longest = max(parts, key=len)
        if len(longest) >= min_poses:
            out.append((frame[longest], poses[longest]))
    return out


#: The arm bones, (parent, joint), each parent before its joint: upper arms, forearms. (The legs
#: are left as interpolated: a foot planted on the floor at two poses stays there between them.)
ARM_BONES = np.array([(INDEX[f"{side}_{a}"], INDEX[f"{side}_{b}"]) for a, b in
                      (("shoulder", "elbow"), ("elbow", "wrist")) for side in ("left", "right")])


def play_motion(frames: np.ndarray, poses: np.ndarray, times_s: np.ndarray) -> np.ndarray:
    """A bank motion at ``times_s: (T,)`` seconds from its first pose, bouncing back and forth
    over its length, interpolated between its poses: linearly, then each arm bone turned back
    to its length (:func:`keep_arm_lengths`; a forearm swinging between two samples would
    otherwise shrink, by up to a third). -> ``(T, 17, 3)``."""
    seconds = (frames - frames[0]) / BANK_RATE_HZ
    length = seconds[-1]
    t = length - np.abs(np.mod(times_s, 2 * length) - length)                     # reflect into [0, length]
    bones = np.linalg.norm(poses[:, ARM_BONES[:, 1]] - poses[:, ARM_BONES[:, 0]], axis=-1)     # (M, 4)
    X = _interpolate(t, seconds, poses).reshape(len(t), NUM_JOINTS, 3)
    return keep_arm_lengths(X, _interpolate(t, seconds, bones))


def _interpolate(t: np.ndarray, times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values: (M, ...)`` at ``times: (M,)`` linearly interpolated at ``t: (T,)`` -> ``(T, K)`` (flattened)."""
    flat = values.reshape(len(values), -1)
    return np.stack([np.interp(t, times, flat[:, k]) for k in range(flat.shape[1])], -1)


def keep_arm_lengths(X: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """``X: (T, 17, 3)`` with each arm bone (:data:`ARM_BONES`) set to ``lengths: (T, 4)`` along
    its direction, from the shoulders outwards (an elbow's bone is set before its wrist's)."""
    X = X.copy()
    for k, (parent, joint) in enumerate(ARM_BONES):
        bone = X[:, joint] - X[:, parent]
        X[:, joint] = X[:, parent] + bone * (lengths[:, k] / np.linalg.norm(bone, axis=-1))[:, None]
    return X


def moving_people(people: int, instants: int, rng: np.random.Generator, rate: float = DEFAULT_FRAME_RATE_HZ,
                  area: float = 1.5, speed: float = 0.8) -> np.ndarray:
    """``(T, G, 17, 3)`` people playing real motions of the pose bank (each from a random
    moment of a random motion) while drifting in straight lines (bouncing inside a square of
    half-side ``area``), turned to face where they go."""
    motions = bank_motions()
    choice = rng.choice(len(motions), people, replace=people > len(motions))
    time = np.arange(instants) / rate
    bodies = np.stack([play_motion(*motions[m], time + rng.uniform(0, 30)) for m in choice], 1)  # (T, G, 17, 3)
    start = rng.uniform(-area, area, (people, 2))
    heading = rng.uniform(0, 2 * np.pi, people)
    velocity = rng.uniform(0, speed, (people, 1)) * np.stack([np.cos(heading), np.sin(heading)], 1)
    raw = start[None] + time[:, None, None] * velocity[None]                      # (T, G, 2)
    pos = area - np.abs(np.mod(raw + area, 4 * area) - 2 * area)                   # reflect into the square
    step = np.diff(pos, axis=0, prepend=pos[:1] - velocity[None] / rate)
    yaw = np.unwrap(np.arctan2(step[..., 1], step[..., 0]), axis=0) - np.pi / 2  # the body faces +y
    width = max(1, int(TURN_S * rate))                                            # turn smoothly at a wall
    padded = np.concatenate([np.repeat(yaw[:1], width, 0), yaw, np.repeat(yaw[-1:], width, 0)])
    kernel = np.ones(2 * width + 1) / (2 * width + 1)
    yaw = np.stack([np.convolve(padded[:, g], kernel, "valid") for g in range(people)], 1)
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    x = c * bodies[..., 0] - s * bodies[..., 1] + pos[..., 0:1]
    y = s * bodies[..., 0] + c * bodies[..., 1] + pos[..., 1:2]
    return np.stack([x, y, bodies[..., 2]], -1)


def record_rig(calibration: RigCalibration, poses3d: np.ndarray, offsets: np.ndarray, frames: int,
               rng: np.random.Generator, errors: DetectorErrors = DetectorErrors()
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What each camera's detector sees: camera ``c``'s frame ``f`` shows
    ``poses3d[f + offsets[c] - offsets.min()]``.

    Args:
        poses3d: ``(S, G, 17, 3)`` with ``S >= frames + offsets.max() - offsets.min()``.
    Returns:
        ``keypoints (N, 17, 3)`` distorted pixels, ``camera (N,)``, ``frame (N,)``, ``person (N,)``,
        sorted by camera, then frame.
    """
    kps, cams, fr, per = [], [], [], []
    for s in range(len(poses3d)):
        k, c, p = detect_views(calibration.cameras, poses3d[s], rng, errors)
        f = s + offsets.min() - offsets[c]
        keep = (f >= 0) & (f < frames)
        kps.append(k[keep])
        cams.append(c[keep])
        fr.append(f[keep])
        per.append(p[keep])
    keypoints, camera, frame, person = (np.concatenate(a) for a in (kps, cams, fr, per))
    order = np.lexsort((frame, camera))
    return keypoints[order].reshape(-1, NUM_JOINTS, 3), camera[order], frame[order], person[order]


def simulate_rig(config: RigSimConfig = RigSimConfig()) -> RigSimulation:
    """Simulate a rig capture with ``config`` (reproducible from ``config.seed``)."""
    rng = np.random.default_rng(config.seed)
    V = config.cameras
    cameras = ring_cameras(V, config.radius, config.height, config.focal_px, (config.image_width, config.image_height),
                           names=tuple(f"cam_{i + 1:02d}" for i in range(V)))
    distortions = tuple(np.array([config.distortion * (0.5 + 0.5 * i / max(V - 1, 1)), 0.0, 0.0, 0.0])
                        for i in range(V))
    calibration = RigCalibration(replace(cameras, distortion=distortions), {"units": "m"})
    offsets = config.camera_offsets()
    S = config.frames + offsets.max() - offsets.min()
    poses3d = moving_people(config.people, S, rng, config.frame_rate, config.area, config.speed)
    keypoints, camera, frame, person = record_rig(calibration, poses3d, offsets, config.frames, rng, config.errors)
    instants = np.arange(S) + offsets.min()
    return RigSimulation(calibration, offsets, instants, poses3d, keypoints, camera, frame, person,
                         pose_scores(keypoints), config.frames, config.frame_rate)
