"""One rigid skeleton per track: robust bone lengths over a track's instants, and the rig's
refinement of every person against its 2D keypoints, the pose prior and its track's bones.

Pure numpy (and the core refinement); no I/O.
"""
from __future__ import annotations

import numpy as np

from mvm.core.blas import one_blas_thread
from mvm.core.image_units import in_person_sizes, view_sizes
from mvm.core.keypoints import BONES, bone_lengths
from mvm.core.quality import reprojection_errors
from mvm.core.refine_units import prior_weights
from mvm.core.scene import Cameras, Poses2D
from mvm.rig.instants import InstantPersons


def track_bone_lengths(X: np.ndarray, track: np.ndarray, min_count: int = 3) -> np.ndarray:
    """The median length of every bone over each track's instants, given to each person.

    ``X: (Q, 17, 3)`` (NaN: missing), ``track: (Q,)`` -> ``(Q, B)``; NaN for a bone seen at fewer
    than ``min_count`` instants of its track. The median ignores the instants where a swap or an
    outlier bent a bone."""
    lengths = bone_lengths(X)                                                     # (Q, B)
    track = np.asarray(track)
    ids, index = np.unique(track, return_inverse=True)
    B = lengths.shape[1]
    key = (index[:, None] * B + np.arange(B)).ravel()                             # (Q B,)
    values = lengths.ravel()
    ok = np.isfinite(values)
    key, values = key[ok], values[ok]
    n = len(ids) * B
    order = np.lexsort((values, key))
    counts = np.bincount(key, minlength=n)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    median = np.full(n, np.nan)
    has = counts >= max(min_count, 1)
    sorted_values = values[order]
    median[has] = 0.5 * (sorted_values[(starts + (counts - 1) // 2)[has]] + sorted_values[(starts + counts // 2)[has]])
    return median.reshape(len(ids), B)[index]


def bone_length_cv(X: np.ndarray, track: np.ndarray, min_count: int = 3) -> np.ndarray:
    """Coefficient of variation (std / mean) of every bone within every track: ``(K, B)`` for the
    ``K`` tracks in id order, NaN where a bone has fewer than ``min_count`` lengths."""
    lengths = bone_lengths(X)
    out = []
    for k in np.unique(track):
        L = lengths[np.asarray(track) == k]
        count = np.isfinite(L).sum(0)
        with np.errstate(invalid="ignore", divide="ignore"):
            cv = np.nanstd(L, axis=0) / np.nanmean(L, axis=0) if len(L) else np.full(L.shape[1], np.nan)
        out.append(np.where(count >= min_count, cv, np.nan))
    return np.array(out).reshape(-1, len(BONES))


def observations(persons: InstantPersons, detections: Poses2D, cameras: Cameras,
                 keypoint_threshold: float = 0.0):
    """The 2D keypoints each person was triangulated from, per camera.

    Returns ``xy: (Q, V, 17, 2)``, ``conf: (Q, V, 17)`` (0 where no keypoint),
    ``P: (Q, V, 3, 4)`` (zeros where the camera has no member) and ``used: (Q, V, 17)`` (the
    triangulation's inliers)."""
    members = persons.members                                                     # (Q, V)
    has = members >= 0
    kp = detections.keypoints[np.maximum(members, 0)]                             # (Q, V, 17, 3)
    conf = np.where(has[..., None] & (kp[..., 2] >= keypoint_threshold), kp[..., 2], 0.0)
    P = np.where(has[..., None, None], cameras.P[None], 0.0)
    return kp[..., :2], conf, P, persons.inliers & has[..., None] & (conf > 0)


def detection_sizes(persons: InstantPersons, detections: Poses2D, keypoint_threshold: float) -> np.ndarray:
    """``(Q, V)`` the unit of image distances of each person's detection in each camera, px
    (:func:`mvm.core.image_units.view_sizes`; 1 where the camera has no member)."""
    members = persons.members
    return np.where(members >= 0, view_sizes(detections, keypoint_threshold)[np.maximum(members, 0)], 1.0)


def refit(persons: InstantPersons, X: np.ndarray, detections: Poses2D, cameras: Cameras) -> InstantPersons:
    """``persons`` with joints ``X: (Q, 17, 3)`` and their reprojection errors recomputed."""
    xy, _, P, used = observations(persons, detections, cameras)
    errors = np.where(persons.valid, reprojection_errors(X, xy, P), np.nan)
    used = used & np.isfinite(X).all(-1)[:, None, :]
    n = used.sum((1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        person_error = np.where(n > 0, np.where(used, errors, 0.0).sum((1, 2)) / n, np.nan)
    return InstantPersons(X, persons.instant, persons.scores, persons.members, persons.inliers, persons.valid,
                          errors, person_error)


def capture_noise_factor(persons: InstantPersons, detections: Poses2D, config) -> float:
    """The detector noise of a rig's capture relative to the noise the settings are set for, as
    :func:`mvm.core.refine_units.noise_factor` gives it for a scene: the threshold
    :func:`mvm.core.refine_units.noise_threshold` of the noise over ``ransac_threshold``; 1 where the
    threshold is held or nothing measures the noise.

    The noise is measured once for the whole capture (its persons' triangulation), not per
    instant: the refinement shares tracks out among processes, and the noise is the detector's.
    As :func:`mvm.core.triangulate.residual_sigma` measures it: the median of the inliers'
    reprojection errors in person sizes, each scaled by ``sqrt(2n / (2n - 3))`` for the 3
    coordinates its joint's ``n`` inliers fitted (joints of three inliers or more: two views agree
    on a point whatever they saw), taken as a Gaussian's cut at the threshold that noise gives
    (:func:`mvm.core.triangulate.rayleigh_sigma`; the instants' own thresholds are not kept)."""
    from mvm.core.refine_units import noise_factor, noise_threshold
    from mvm.core.triangulate import RAYLEIGH_MEDIAN, rayleigh_sigma

    if not len(persons) or not config.ransac or config.ransac_threshold_sigmas <= 0:
        return 1.0
    n = persons.inliers.sum(1)                                                     # (Q, 17)
    used = persons.inliers & (n >= 3)[:, None, :] & np.isfinite(persons.errors)
    if not used.any():
        return 1.0
    size = detection_sizes(persons, detections, config.keypoint_threshold)         # (Q, V)
    with np.errstate(divide="ignore", invalid="ignore"):
        scaled = persons.errors / size[..., None] * np.sqrt(2 * n / (2 * n - 3))[:, None, :]
    m = np.array([np.median(scaled[used])])
    cut = noise_threshold(m / RAYLEIGH_MEDIAN, config)                             # the cut that noise gives
    return float(noise_factor(noise_threshold(rayleigh_sigma(m, cut), config), config)[0])


#: Re-linearizations of the robust loss and the prior in a rig's refinement (:func:`refine_tracks`).
OUTER_ITERATIONS = 2
#: Relative change at which a person's inner solve stops in a rig's refinement.
TOLERANCE = 1e-5


def refine_tracks(persons: InstantPersons, track: np.ndarray, detections: Poses2D, cameras: Cameras,
                  config, prior=None, bone_weight: float = 0.32, outer_iterations: int = OUTER_ITERATIONS,
                  tolerance: float = TOLERANCE, noise: float = 1.0,
                  lengths: np.ndarray | None = None) -> InstantPersons:
    """Refine every person against its 2D keypoints, the pose prior and its track's bone lengths
    (:func:`track_bone_lengths` of the triangulated joints, a soft term of weight
    ``bone_weight``, squared person sizes per squared relative length error: the reprojection
    residuals are in person sizes, :mod:`mvm.core.image_units`). ``config``: a
    :class:`mvm.core.config.Config` (prior weight, following each person's views' spread as in
    :func:`mvm.core.refine_units.prior_weights`; robust scale, iterations). Once the lengths
    are fixed the persons are independent: one call of :func:`mvm.core.refine.refine_poses`
    solves all of them, with BLAS on one thread (its matrices are small: threads only cost).
    ``tolerance``: the relative change at which a person's inner solve stops (on the rig
    benchmark 1e-5 reaches the objective of 1e-8 to within 3e-5 of it, 99.5 % of the joints
    within 0.5 mm and 90 % within 0.05 mm, with 43 % of the solves); ``outer_iterations``:
    re-linearizations of the robust loss and the prior (two: a third costs a quarter more time
    and lowers the objective by 0.5 % on the rig benchmark, but leaves the poses as good:
    Panoptic 5 cameras PCP 0.997 and 16.9 mm either way, mean reprojection error 4.11 px with
    three and 4.105 with two on the rig benchmark). ``noise``: the capture's
    :func:`capture_noise_factor`; the residuals are in person sizes times it, so that the robust
    scale grows with the noise and the prior and the bones weigh against the keypoints as the
    noise's variance, as in a scene's refinement. ``lengths: (Q, B)``: the bone lengths to hold
    (None: :func:`track_bone_lengths` of ``persons``)."""
    from mvm.core.refine import refine_poses

    if not len(persons):
        return persons
    lengths = track_bone_lengths(persons.X, track) if lengths is None else lengths  # (Q, B)
    xy, conf, P, used = observations(persons, detections, cameras, config.keypoint_threshold)
    xy, P = in_person_sizes(xy, P, detection_sizes(persons, detections, config.keypoint_threshold) * noise)
    centers = np.broadcast_to(cameras.centers, (len(persons.X), *cameras.centers.shape))
    weights = prior_weights(config, persons.X, centers, used.any(-1))                # the views' spread
    with one_blas_thread(), np.errstate(all="ignore"):   # small matrices
        X = refine_poses(persons.X, xy, conf, P, used, prior, weights, config.robust_scale,
                         config.refine_max_iterations, bone_lengths=lengths, bone_weight=bone_weight,
                         outer_iterations=outer_iterations, tolerance=tolerance).X
    X = np.where(np.isfinite(X).all(-1, keepdims=True), X, np.nan)
    return refit(persons, X, detections, cameras)
