"""Synthetic mannequin scenes with ground truth: frozen people, a hand-held camera touring
them, and 2D detections with a detector's errors. The scene's settings (:class:`SimConfig`,
its :data:`PRESETS`) and its assembly (:func:`simulate`); the parts live in
:mod:`mvm.sim.people`, :mod:`mvm.sim.tours`, :mod:`mvm.sim.projection` and
:mod:`mvm.sim.detector`, the ground-truth file in :mod:`mvm.io.ground_truth`.

World frame: metres, z up, floor at z = 0. The simulated COLMAP model *is* the world, so
estimates compare with the truth directly (no alignment).

Randomness: everything the first version of this simulator drew comes from one generator
seeded with ``seed``, in the same order, so ``SimConfig(people=6, frames=100, seed=s)`` keeps its
scene; the later features (postures, close pairs, look-alikes, merged poses, real
trajectories) draw from a second generator seeded with ``(seed, 1)`` and only when enabled.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from mvm.core.config import check_settings, setting
from mvm.core.scene import Poses2D, Scene
from mvm.io.ground_truth import GroundTruth
from mvm.sim.detector import DETECTOR_FIELDS, DetectorErrors, detect_people, detector_level, pose_scores
from mvm.sim.people import clothes, place_people
from mvm.sim.projection import project_people
from mvm.sim.tours import camera_tour, look_at, trajectory_tour

__all__ = ["SimConfig", "PRESETS", "simulate", "look_at", "DetectorErrors"]


@dataclass(frozen=True)
class SimConfig:
    """A simulated scene. Lengths in metres, angles in degrees.

    The detector's settings are ``detector`` (:class:`~mvm.sim.detector.DetectorErrors`, noise
    as a fraction of the person's image size); :meth:`preset` and :meth:`replace` also take
    them by their own names (``noise=0.01``)."""

    #: People in the scene; more crowds the views. [people]
    people: int = setting(6, ge=1, le=1000)
    #: Frames of the camera's tour; more gives more views of everyone. [frames]
    frames: int = setting(100, ge=2, le=100_000)
    #: Image width; the field of view follows with ``focal_px``. [px]
    image_width: int = setting(1280, ge=16, le=16384)
    #: Image height. [px]
    image_height: int = setting(720, ge=16, le=16384)
    #: Focal length; lower widens the field of view. [px]
    focal_px: float = setting(1000.0, gt=0)
    #: Total angle of the camera's tour around the crowd; wider gives more parallax. [deg]
    arc_deg: float = setting(60.0, gt=0, le=360)
    #: Distance of the camera path from the crowd's centre. [m]
    camera_distance: float = setting(5.0, gt=0)
    #: Height of the camera above the floor. [m]
    camera_height: float = setting(1.6, ge=0)
    #: Hand-held shake: rotation jitter of the camera (standard deviation). [deg]
    shake_deg: float = setting(0.5, ge=0, le=90)
    #: Hand-held shake: position jitter and vertical bob of the camera. [m]
    shake_m: float = setting(0.02, ge=0)
    #: People stand in a disc of this radius; smaller packs them closer. [m]
    crowd_radius: float = setting(2.0, gt=0)
    #: People stand at least this far apart (pelvis). [m]
    min_separation: float = setting(0.7, ge=0)
    #: Every person's nearest neighbour stands at most this far (pelvis); None: no bound. [m]
    max_separation: float | None = setting(None, gt=0)
    #: Range of the body size factor applied to the bank's poses (low, high). [1]
    size_range: tuple[float, float] = (0.85, 1.1)
    #: The detector's errors (a table of their own: ``[simulate.detector]``). [-]
    detector: DetectorErrors = DetectorErrors(noise=0.008, outlier_joint_prob=0.01)
    # --- appearance -----------------------------------------------------------------------
    #: Length of each pose's appearance descriptor. [numbers]
    appearance_dim: int = setting(16, ge=1, le=4096)
    #: Noise of the appearance descriptors; higher makes appearance less telling. [1]
    appearance_noise: float = setting(0.15, ge=0)
    #: Multiplicative lighting drift over the tour. [fraction]
    lighting_drift: float = setting(0.2, ge=0)
    #: Persons share the same clothes (appearance is useless). [bool]
    identical_clothes: bool = False
    # --- later additions (defaults leave the scene as the first version made it) ----------
    #: Fractions of standing, sitting and crouching people (the bank's labels); None draws
    #: any pose of the bank. [fractions]
    postures: tuple[float, float, float] | None = None
    #: Number of people placed side by side with another one, ``close_distance`` apart. [people]
    close_pairs: int = setting(0, ge=0)
    #: Distance between the people of a close pair. [m]
    close_distance: float = setting(0.45, ge=0)
    #: Bodies of different people keep at least this horizontal distance between joints. [m]
    body_clearance: float = setting(0.08, ge=0)
    #: Number of people wearing near-identical clothes to another person. [people]
    lookalikes: int = setting(0, ge=0)
    #: A RealEstate10K / MannequinChallenge camera file: the tour follows its path (resampled
    #: to ``frames``, bent onto the ``arc_deg`` tour and scaled to the room) and its intrinsics;
    #: None: a smooth arc. [path]
    trajectory: str | None = None
    #: Seed of every random draw: the same settings give the same scene. [1]
    seed: int = setting(0, ge=0, le=2**63 - 1)

    def __post_init__(self):
        check_settings(self)

    @classmethod
    def preset(cls, name: str, **overrides) -> SimConfig:
        """A preset of :data:`PRESETS` ('clean', 'realistic', 'hard', 'crowd', 'precise', 'heavy') with
        ``overrides`` applied (scene or detector settings, by name). A 'crowd' of another
        number of people keeps its density: its disc (:func:`crowd_radius`) and its false poses
        (a tenth of the true ones) follow ``people`` unless given."""
        if name not in PRESETS:
            raise ValueError(f"unknown preset {name!r}; known: {', '.join(PRESETS)}")
        if name == "crowd" and "people" in overrides:            # the disc and the false poses follow the crowd
            people = overrides["people"]
            overrides = {"crowd_radius": crowd_radius(people), "false_pose_rate": 0.1 * people, **overrides}
        return cls().replace(**{**PRESETS[name], **overrides})

    def replace(self, **changes) -> SimConfig:
        """A copy with ``changes``: fields of the scene, or of the detector by their names."""
        detector = {k: changes.pop(k) for k in list(changes) if k in DETECTOR_FIELDS}
        if detector:
            changes["detector"] = dataclasses.replace(changes.get("detector", self.detector), **detector)
        return dataclasses.replace(self, **changes)


def crowd_radius(people: int) -> float:
    """Radius of the disc of a frozen crowd of ``people`` (with ``min_separation`` 0.6 m and
    ``max_separation`` 1.0 m, the nearest neighbours stand 0.6-1.0 m apart, median 0.73 m). [m]"""
    return 0.3 + 0.55 * float(np.sqrt(people))


#: Presets. 'clean': exact projections (only frame borders and occlusion hide joints);
#: 'realistic': errors of a good bottom-up detector on crowded frames; 'hard': a poor
#: detector, crowded and look-alike people; 'crowd': a frozen crowd as dense as the real ones
#: (12 people 0.6-1.0 m apart, standing and seated, of similar sizes, a 1080p camera at eye
#: height 5.5 m away; noise 1.5 % of the person's size, 5 % dropout, 2 % swaps, 1 % outliers,
#: false poses 10 % of the true ones), see :mod:`mvm.eval.crowd` for the scenes drawn around it;
#: 'precise' and 'heavy': the 'realistic' scene seen by the most and the least accurate of
#: :data:`mvm.sim.detector.DETECTOR_LEVELS` (noise 0.5 % and 3 % of the person's size).
PRESETS: dict[str, dict] = {
    "clean": dict(noise=0.0, dropout=0.0, swap_prob=0.0, outlier_joint_prob=0.0, false_pose_rate=0.0,
                  merge_prob=0.0, appearance_noise=0.05, lighting_drift=0.0, shake_deg=0.2),
    "realistic": dict(noise=0.008, dropout=0.03, swap_prob=0.01, outlier_joint_prob=0.01,
                      false_pose_rate=0.1, merge_prob=0.01, appearance_noise=0.15, lighting_drift=0.2,
                      postures=(0.6, 0.3, 0.1), close_pairs=1, lookalikes=1),
    "hard": dict(noise=0.015, dropout=0.08, swap_prob=0.03, outlier_joint_prob=0.03,
                 false_pose_rate=0.5, merge_prob=0.03, appearance_noise=0.3, lighting_drift=0.4,
                 postures=(0.4, 0.4, 0.2), close_pairs=2, lookalikes=2, shake_deg=1.0),
    "crowd": dict(people=12, frames=150, arc_deg=60.0, camera_distance=5.5, camera_height=1.6,
                  image_width=1920, image_height=1080, focal_px=1500.0, shake_deg=0.8, shake_m=0.03,
                  crowd_radius=crowd_radius(12), min_separation=0.6, max_separation=1.0,
                  size_range=(0.92, 1.06), postures=(0.6, 0.35, 0.05),
                  noise=0.015, dropout=0.05, swap_prob=0.02, outlier_joint_prob=0.01,
                  false_pose_rate=0.1 * 12, merge_prob=0.0, appearance_noise=0.2, lighting_drift=0.2,
                  lookalikes=2),
}
for _level in ("precise", "heavy"):
    PRESETS[_level] = {**PRESETS["realistic"], **dataclasses.asdict(detector_level(_level, SimConfig.people))}


def simulate(config: SimConfig | None = None, bank_poses: np.ndarray | None = None,
             bank_labels: np.ndarray | None = None) -> tuple[Scene, GroundTruth]:
    """Simulate a mannequin scene: ``(Scene, GroundTruth)``.

    Poses come from the shipped pose bank (complete poses, with their posture labels) unless
    ``bank_poses: (B, 17, 3)`` (bank frame) and optionally ``bank_labels: (B,)`` are given.
    """
    config = config or SimConfig()
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
    base = clothes(config, rng, extra)
    uv, depth = project_people(cams, poses3d)
    lighting = 1.0 + config.lighting_drift * np.linspace(-0.5, 0.5, len(cams))
    found = detect_people(uv, depth, cams.size, cams.focal, config.detector, rng, extra=extra, clothes=base,
                          appearance_noise=config.appearance_noise, lighting=lighting, false_poses_from="scene")
    N = len(found.keypoints)
    appearance = found.appearance if config.appearance_dim else None
    poses2d = Poses2D(found.keypoints, found.view, np.arange(1, N + 1), pose_scores(found.keypoints), appearance)
    scene = Scene("simulated", cams, poses2d)
    return scene, GroundTruth(poses3d, found.person, posture, found.merged_with)
