"""The one error model of a simulated 2D pose detector, used by the mannequin scenes and by the
synthetic rigs.

Per person and view, joints outside the frame or behind another person (depth-ordered,
:func:`mvm.sim.projection.occluded_joints`) are lost; the others get Gaussian noise of
``noise`` times the person's image size, random ``dropout``, gross outliers and, per pose, a
left-right swap; confidences fall with the error. Pairs of overlapping people may merge into
one pose (``merge_prob``) and false poses are added (``false_pose_rate`` per view, Poisson).

Randomness: the draws are made person by person in a fixed order (dropout, noise, confidence,
outliers, swap, then the appearance descriptor when there is one); merges draw from a second
generator. Drawing all people of a view at once would be faster but would change every
simulated scene, so the per-person order is kept; the geometry (frame, occlusion, sizes) is
computed for all people of a view at once.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mvm.core.config import check_settings, setting
from mvm.core.keypoints import FLIP_PERMUTATION, NUM_JOINTS
from mvm.sim.projection import image_size_of_people, in_frame, occluded_joints

#: A person is detected only when at least this tall in the image. [px]
MIN_PERSON_PX = 20.0
#: Joints a merged pose takes from its second person (the lower body).
_LOWER_BODY = np.arange(11, 17)


@dataclass(frozen=True)
class DetectorErrors:
    """Errors of a simulated 2D detector (probabilities per joint unless said otherwise)."""

    #: Joint noise (standard deviation) as a fraction of the person's image size; higher blurs
    #: the keypoints more. [fraction]
    noise: float = setting(0.01, ge=0, le=1)
    #: Probability that a visible joint is missed. [0-1]
    dropout: float = setting(0.03, ge=0, le=1)
    #: Joints behind another person (depth-ordered) are lost. [bool]
    occlusion: bool = True
    #: Probability that a pose has left and right swapped (per pose). [0-1]
    swap_prob: float = setting(0.01, ge=0, le=1)
    #: Probability that a joint lands about a quarter of the person's size away. [0-1]
    outlier_joint_prob: float = setting(0.02, ge=0, le=1)
    #: False poses per view (Poisson mean); higher clutters every view more. [poses]
    false_pose_rate: float = setting(0.1, ge=0, le=1000)
    #: Probability that two overlapping people are detected as one pose (per overlapping pair). [0-1]
    merge_prob: float = setting(0.0, ge=0, le=1)
    #: A person with fewer visible joints than this is not detected. [joints]
    min_visible: int = setting(5, ge=0, le=17)

    def __post_init__(self):
        check_settings(self)


#: The names of the detector's settings (accepted flat by ``SimConfig.preset`` and ``replace``).
DETECTOR_FIELDS: tuple[str, ...] = tuple(DetectorErrors.__dataclass_fields__)

#: Detectors from precise to poor, spanning the errors of real ones: noise (fraction of the
#: person's image size), dropout, swaps, outlier joints, and false poses as a fraction of the
#: true ones (``false_pose_fraction``; :func:`detector_level` turns it into a rate per view).
#: 'realistic' is the default :class:`DetectorErrors`, 'crowd' the crowd benchmark's
#: (:mod:`mvm.eval.crowd`), 'heavy' a poor detector on hard footage.
DETECTOR_LEVELS: dict[str, dict] = {
    "precise": dict(noise=0.005, dropout=0.02, swap_prob=0.0, outlier_joint_prob=0.005, false_pose_fraction=0.05),
    "realistic": dict(noise=0.01, dropout=0.03, swap_prob=0.01, outlier_joint_prob=0.02, false_pose_fraction=0.1),
    "crowd": dict(noise=0.015, dropout=0.05, swap_prob=0.02, outlier_joint_prob=0.01, false_pose_fraction=0.1),
    "heavy": dict(noise=0.03, dropout=0.15, swap_prob=0.05, outlier_joint_prob=0.04, false_pose_fraction=0.4),
}


def detector_level(name: str, people: int) -> DetectorErrors:
    """The detector of :data:`DETECTOR_LEVELS` ``name`` for scenes of ``people`` people (the
    false poses per view: the level's fraction of them)."""
    if name not in DETECTOR_LEVELS:
        raise ValueError(f"unknown detector level {name!r}; known: {', '.join(DETECTOR_LEVELS)}")
    level = dict(DETECTOR_LEVELS[name])
    fraction = level.pop("false_pose_fraction")
    return DetectorErrors(**level, false_pose_rate=fraction * people)


@dataclass
class SimulatedDetections:
    """Detections of every view, in view order.

    Attributes:
        keypoints: ``(N, 17, 3)`` x, y (px), confidence (0: not detected).
        view: ``(N,)`` view of every pose.
        person: ``(N,)`` true person (-1: a false pose); for a merged pose, its upper body's.
        merged_with: ``(N,)`` the person a merged pose took its lower body from, -1 otherwise.
        appearance: ``(N, D)`` descriptors (None when no clothes were given).
    """

    keypoints: np.ndarray
    view: np.ndarray
    person: np.ndarray
    merged_with: np.ndarray
    appearance: np.ndarray | None


def pose_scores(keypoints: np.ndarray) -> np.ndarray:
    """Mean confidence of the present joints. ``(N, 17, 3)`` -> ``(N,)``."""
    present = keypoints[..., 2] > 0
    return np.where(present, keypoints[..., 2], 0).sum(1) / np.maximum(present.sum(1), 1)


def _detect_person(uv: np.ndarray, visible: np.ndarray, size: float, errors: DetectorErrors,
                   rng: np.random.Generator) -> np.ndarray:
    """One person's detection: ``uv: (17, 2)`` true pixels, ``visible: (17,)`` joints seen,
    ``size`` its image size (px) -> keypoints ``(17, 3)``."""
    sigma = errors.noise * size
    err = rng.normal(scale=sigma, size=(NUM_JOINTS, 2))
    xy = uv + err
    conf = np.clip(0.95 - 0.5 * np.linalg.norm(err, axis=1) / max(3 * sigma, 1e-9)
                   + rng.normal(0, 0.03, NUM_JOINTS), 0.3, 1.0)
    outlier = rng.uniform(size=NUM_JOINTS) < errors.outlier_joint_prob
    xy[outlier] += rng.normal(scale=0.25 * size, size=(outlier.sum(), 2))
    conf[outlier] = rng.uniform(0.3, 0.7, outlier.sum())
    if rng.uniform() < errors.swap_prob:
        xy, conf, visible = xy[FLIP_PERMUTATION], conf[FLIP_PERMUTATION], visible[FLIP_PERMUTATION]
    kp = np.zeros((NUM_JOINTS, 3))
    kp[visible, :2] = xy[visible]
    kp[visible, 2] = conf[visible]
    return kp


def _false_pose(source: np.ndarray, width: float, height: float, rng: np.random.Generator) -> np.ndarray:
    """A false pose ``(17, 3)``: a copy of ``source: (17, 3)`` shifted in the image, with low
    confidences, cut at the frame."""
    kp = source.copy()
    kp[kp[:, 2] > 0, :2] += rng.uniform([-width / 3, -height / 6], [width / 3, height / 6])
    kp[:, 2] *= rng.uniform(0.3, 0.6)
    kp[(kp[:, 0] < 0) | (kp[:, 0] >= width) | (kp[:, 1] < 0) | (kp[:, 1] >= height)] = 0
    return kp


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


def detect_people(uv: np.ndarray, depth: np.ndarray, image_size: np.ndarray, focal: np.ndarray,
                  errors: DetectorErrors, rng: np.random.Generator, *, present: np.ndarray | None = None,
                  extra: np.random.Generator | None = None, clothes: np.ndarray | None = None,
                  appearance_noise: float = 0.0, lighting: np.ndarray | None = None,
                  false_poses_from: str = "view") -> SimulatedDetections:
    """Simulated detections of ``G`` people in ``V`` views.

    Args:
        uv: ``(V, G, 17, 2)`` exact projections (px); depth: ``(V, G, 17)`` camera z (metres).
        image_size: ``(V, 2)`` width, height (px); focal: ``(V,)`` focal lengths (px).
        present: ``(G, 17)`` joints that exist in the truth (None: all).
        extra: the generator of the merges (needed when ``errors.merge_prob > 0``).
        clothes: ``(G, D)`` appearance of every person; each detection gets it times
            ``lighting: (V,)`` (default 1) plus Gaussian ``appearance_noise``, a false pose a
            uniform random descriptor. None: no descriptors (and no draws for them).
        false_poses_from: a false pose copies a detection of its own view (``"view"``) or any
            detection made so far in the scene (``"scene"``, the mannequin scenes' rule).
    """
    if false_poses_from not in ("view", "scene"):
        raise ValueError(f"false_poses_from: expected 'view' or 'scene', got {false_poses_from!r}")
    if errors.merge_prob > 0 and extra is None:
        raise ValueError("merge_prob > 0 needs the generator of the merges (extra)")
    V, G = uv.shape[:2]
    lists: dict[str, list] = dict(keypoints=[], views=[], person=[], merged_with=[], apps=[])
    keypoints, views, person, merged_with, apps = lists.values()
    for v in range(V):
        W, H = image_size[v]
        inside = in_frame(uv[v], depth[v], W, H)
        if present is not None:
            inside &= present
        hidden = occluded_joints(uv[v], depth[v], focal[v]) if errors.occlusion else np.zeros_like(inside)
        size = image_size_of_people(uv[v], inside)                                          # (G,)
        start = len(keypoints)
        for g in range(G):
            visible = inside[g] & ~hidden[g] & (rng.uniform(size=NUM_JOINTS) >= errors.dropout)
            if visible.sum() < errors.min_visible or size[g] < MIN_PERSON_PX:
                continue
            keypoints.append(_detect_person(uv[v, g], visible, size[g], errors, rng))
            views.append(v)
            person.append(g)
            merged_with.append(-1)
            apps.append(None if clothes is None else
                        clothes[g] * (1.0 if lighting is None else lighting[v])
                        + rng.normal(0, appearance_noise, clothes.shape[1]))
        if errors.merge_prob > 0:
            _merge_in_view(lists, start, errors.merge_prob, extra)
        pool = start if false_poses_from == "view" else 0
        for _ in range(rng.poisson(errors.false_pose_rate)):
            if len(keypoints) == pool:
                break
            keypoints.append(_false_pose(keypoints[pool + rng.integers(len(keypoints) - pool)], W, H, rng))
            views.append(v)
            person.append(-1)
            merged_with.append(-1)
            apps.append(None if clothes is None else rng.uniform(0, 1, clothes.shape[1]))
    N = len(keypoints)
    appearance = None if clothes is None else np.clip(np.array(apps).reshape(N, clothes.shape[1]), 0, None)
    return SimulatedDetections(np.array(keypoints).reshape(N, NUM_JOINTS, 3), np.array(views, dtype=int),
                               np.array(person, dtype=int), np.array(merged_with, dtype=int), appearance)
