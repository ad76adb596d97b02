"""Limb joints through the occlusions of a track: the track's own motion, its bone lengths,
the pose prior and the rays of the views that still see the joint
(:func:`mvm.core.gap_fit.fit_gaps`), with a confidence that falls as the fill's uncertainty
grows (towards the middle of a gap, with its length, away from the views that see it).

The limb joints refused as outliers (:mod:`mvm.rig.refusals`: their views or their bone dispute
them) are filled as missing ones; the rig's driver leaves them out of the smoothing, and
completes those the fill cannot fill as other missing joints. Through a run with a refused
joint a ray is used only where it agrees with the track's prediction, and a view only if its
rays agree where the gap begins and ends (a detector that reports another thing in a view does
it through the stretch, and its rays jump off the joint's path there).

A joint is filled over a run of missing instants when its parent joint (the shoulder of an
elbow, the elbow of a wrist, the hip of a knee, the knee of an ankle) is known over the whole
run and both are seen on at least one side of it (a run at a track's end is continued from the
side it has); elbows and knees first, so a wrist hidden with its elbow is filled from the
filled elbow. The instants a track missed whole (the person was not found there) are carried
through by the motion, nothing written at them. Long runs and those at a track's end are
flagged ``inferred``, brief ones ``interpolated``. Pure numpy; no I/O.
"""
from __future__ import annotations

import numpy as np

from mvm.core.completion import INFERRED, INTERPOLATED, complete_tracks, take_rows, track_rows
from mvm.core.gap_fit import fit_gaps
from mvm.core.keypoints import INDEX
from mvm.core.triangulate import RAYLEIGH_MEDIAN
from mvm.rig.tracking import runs

#: (joint, parent) pairs filled in two passes: the parents of the second are in the first.
LIMB_PASSES = tuple(tuple((INDEX[f"{s}_{j}"], INDEX[f"{s}_{p}"]) for s in ("left", "right") for j, p in pairs)
                    for pairs in ((("elbow", "shoulder"), ("knee", "hip")), (("wrist", "elbow"), ("ankle", "knee"))))
#: The joints filled, and their parents.
LIMB_JOINTS = [j for joints in LIMB_PASSES for j, _ in joints]
LIMB_PARENTS = [p for joints in LIMB_PASSES for _, p in joints]
#: The elbows and wrists.
ARM_JOINTS = [INDEX[f"{s}_{j}"] for s in ("left", "right") for j in ("elbow", "wrist")]
#: The joints the limb chains hang from (shoulders, hips): interpolated over their own short gaps
#: before the limbs are filled, so that one instant without a shoulder does not break an arm's chain.
ROOT_JOINTS = sorted({p for _, p in LIMB_PASSES[0]})
#: Standard deviation of a bone's length about its track's median, relative to it. [1]
BONE_SIGMA = 0.03
#: Standard deviation of a joint's distance to the ray of a view's keypoint of it, where the
#: capture does not measure its own (:func:`ray_sigma`). [m]
RAY_SIGMA_M = 0.02
#: The smallest such deviation measured on a capture. [m]
MIN_RAY_SIGMA_M = 0.005
#: Fewest rays of inlier keypoints that measure a capture's deviation (:func:`ray_sigma`). [1]
MIN_NOISE_RAYS = 50
#: Rays farther than this from the fill are another person's keypoint or an outlier. [m]
RAY_GATE_M = 0.25
#: Through a run with refused instants (its views disagree: some report another thing), rays
#: farther than this many standard deviations from the motion's and the prior's guess are
#: refused before the fit (:func:`mvm.core.gap_fit.fit_gaps`' ``gate_sigmas``). On the simulated
#: Shelf-like stretches (benchmarks/rig_occlusion.py) 2 refused a view that sees a hidden elbow
#: where the arm's motion turned as the stretch began; 3 lets it through (a whole arm with 2
#: views 38-58 -> 33-46 mm, with 1 view 14-40 -> 15-34 mm; a wrist with 1 view 27-37 -> 28-40 mm,
#: with 2 views 14-15 -> 13-14 mm). [1]
RAY_GATE_SIGMAS = 3.0
#: Standard deviation of the pose prior's guess of a limb joint (its error on hidden wrists). [m]
PRIOR_SIGMA_M = 0.1
#: The prior's weight, relative, where a view that agrees with the track's motion sees a refused
#: joint (:func:`mvm.core.gap_fit.fit_gaps`' ``prior_where_seen``): the prior then picks the depth
#: along that view's ray, and, off alike at every instant of a stretch, drew the fill along it (on
#: a sample 80 mm off where the motion alone gave 13). On the simulated stretches of
#: benchmarks/rig_occlusion.py, 1 -> 0.25 took a ghost arm seen by one view over 40 instants from
#: 56.5 to 40.4 mm; 0 made the long stretches worse (a ghost wrist, 40 instants, 22.6 -> 32.3 mm).
#: Runs of a joint only missing keep the full weight (0.25 there: a wrist seen by one view over
#: 20 and 30 instants 12.2 -> 13.1 and 16.3 -> 17.5 mm, over 40 instants 18.2 -> 17.2). [1]
PRIOR_SEEN_WEIGHT = 0.25
#: The smoothed track's accelerations understate a hidden limb's (the low-pass filter takes the
#: peaks off, and a limb is hidden when it does what the seen ones do not): its motion term's
#: standard deviation is this many times the root mean square of the seen second differences.
#: On the simulated occlusions (benchmarks/rig_occlusion.py) 1 lets the motion outweigh the one
#: view that sees a wrist (it then takes the ray's wrong meeting with the bone's sphere), 4
#: lets it follow the noise. [1]
ACC_SIGMA_FACTOR = 2.0
#: Second differences beyond this many robust standard deviations (1.4826 median absolute
#: values) are a swap's or an outlier's jump, not the limb's motion. [1]
ACC_OUTLIER_SIGMAS = 5.0
#: Smallest standard deviation of an offset's second differences. [m / instant²]
MIN_ACC_SIGMA_M = 0.002
#: Second differences of an offset needed to measure its own; fewer: this default. [m / instant²]
DEFAULT_ACC_SIGMA_M = 0.01
MIN_ACC_SAMPLES = 5
#: A fill whose posterior standard deviation is this has confidence 0.5. [m]
CONFIDENCE_SCALE_M = 0.05


def rays(xy: np.ndarray, conf: np.ndarray, cameras, threshold: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Back-projected rays of 2D keypoints: ``xy: (Q, V, J, 2)`` undistorted pixels in the
    cameras ``(V,)``, ``conf: (Q, V, J)`` -> ``(origin, direction): (Q, V, J, 3)`` (world; unit
    directions), NaN where ``conf <= threshold``."""
    homogeneous = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1)
    back = np.einsum("vji,vjk->vik", cameras.R, np.linalg.inv(cameras.K))          # (V, 3, 3): R^T K^-1
    d = np.einsum("vik,qvxk->qvxi", back, homogeneous)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    ok = (conf > threshold)[..., None]
    origin = np.broadcast_to(cameras.centers[None, :, None], d.shape)
    return np.where(ok, origin, np.nan), np.where(ok, d, np.nan)


def ray_sigma(X: np.ndarray, origin: np.ndarray, direction: np.ndarray, used: np.ndarray,
              unit: float = 1.0) -> float:
    """The standard deviation of a joint's distance to the rays of its keypoints (per axis of a
    ray's normal plane), measured on the capture: the median distance of the observed joints
    ``X: (Q, 17, 3)`` (NaN elsewhere) to the rays ``origin, direction: (Q, V, 17, 3)``
    (:func:`rays`) of the keypoints their triangulation kept, ``used: (Q, V, 17)``, over the median
    of a two-dimensional normal error's length; joints of three such keypoints or more (two rays
    meet wherever they point). At least :data:`MIN_RAY_SIGMA_M`; :data:`RAY_SIGMA_M` where fewer
    than :data:`MIN_NOISE_RAYS` rays measure it. World units (``unit`` per metre)."""
    used = used & (used.sum(1) >= 3)[:, None]
    P = X[:, None] - origin                                                        # (Q, V, 17, 3)
    distance = np.linalg.norm(P - (P * direction).sum(-1, keepdims=True) * direction, axis=-1)
    distance = distance[used & np.isfinite(distance)]
    if len(distance) < MIN_NOISE_RAYS:
        return RAY_SIGMA_M * unit
    return max(float(np.median(distance)) / RAYLEIGH_MEDIAN, MIN_RAY_SIGMA_M * unit)


def _acc_sigma(offsets: np.ndarray, unit: float) -> float:
    """The standard deviation of a hidden offset's second differences, from those of the seen
    ``offsets: (L, 3)`` (NaN: unseen) of its track: :data:`ACC_SIGMA_FACTOR` times their root
    mean square, those beyond :data:`ACC_OUTLIER_SIGMAS` robust standard deviations left out,
    in world units (``unit`` per metre)."""
    acc = offsets[2:] - 2 * offsets[1:-1] + offsets[:-2]
    acc = acc[np.isfinite(acc).all(-1)]
    if len(acc) < MIN_ACC_SAMPLES:
        return DEFAULT_ACC_SIGMA_M * unit
    robust = 1.4826 * np.median(np.abs(acc))                                      # a swap's jumps left out
    acc = acc[(np.abs(acc) <= ACC_OUTLIER_SIGMAS * robust).all(-1)]
    return max(ACC_SIGMA_FACTOR * float(np.sqrt(np.mean(acc ** 2))), MIN_ACC_SIGMA_M * unit)


def _track_gaps(X: np.ndarray, index: np.ndarray, refused: np.ndarray, joints, long_gap: int, max_gap: int,
                unit: float) -> list[tuple]:
    """The runs of one track (``index``, :func:`~mvm.core.completion.track_rows`) its limb ``joints`` ((joint, parent)
    pairs) can be filled over: ``(rows (n,), [the rows of the two instants before], [after] (-1:
    unknown), joint, parent, bone length, sigma_acc, flag, gate_sigmas)``."""
    S = take_rows(X, index)                                                        # (L, 17, 3)
    seen = np.isfinite(S).all(-1)
    disputes = take_rows(refused, index, False)                                    # (L, 17)
    gaps = []
    for j, p in joints:
        offsets = S[:, j] - S[:, p]
        both = seen[:, j] & seen[:, p]
        if both.sum() < 2:
            continue
        length = float(np.median(np.linalg.norm(offsets[both], axis=-1)))
        sigma = _acc_sigma(offsets, unit)
        for a, b in zip(*runs(~seen[:, j])):
            at_start = a > 0 and both[a - 1]
            at_end = b < len(S) and both[b]
            # instants the track missed whole (no row) are carried by the motion, not written
            if not (b - a <= max_gap and (at_start or at_end) and seen[a:b, p][index[a:b] >= 0].all()):
                continue
            before = [index[a - 2] if a >= 2 and both[a - 2] else -1, index[a - 1] if at_start else -1]
            after = [index[b] if at_end else -1, index[b + 1] if b + 1 < len(S) and both[b + 1] else -1]
            flag = INTERPOLATED if at_start and at_end and b - a < long_gap else INFERRED
            gate = RAY_GATE_SIGMAS if disputes[a:b, j].any() else np.inf
            gaps.append((index[a:b], before, after, j, p, length, sigma, flag, gate))
    return gaps


def _fill_group(X: np.ndarray, group: list[tuple], origin: np.ndarray, direction: np.ndarray,
                prior_X: np.ndarray | None, unit: float,
                sigma_ray: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fit ``group``'s gaps (of one length, :func:`_track_gaps`): ``(rows (N, n), joints (N,),
    joint positions (N, n, 3), posterior deviations (N, n))``; rows -1 (and their positions NaN)
    at the instants the track missed whole."""
    rows = np.array([g[0] for g in group])                                         # (N, n)
    j = np.array([g[3] for g in group])
    p = np.array([g[4] for g in group])
    ends = np.array([g[1] + g[2] for g in group])                                  # (N, 4)
    known = X[np.maximum(ends, 0), j[:, None]] - X[np.maximum(ends, 0), p[:, None]]
    known[ends < 0] = np.nan
    absent = (rows < 0)[..., None]                                                 # (N, n, 1)
    at = np.maximum(rows, 0)
    parent = np.where(absent, np.nan, X[at, p[:, None]])                           # (N, n, 3)
    prior = None if prior_X is None else np.where(absent, np.nan, prior_X[at, j[:, None]] - prior_X[at, p[:, None]])
    o = origin[at, :, j[:, None]] - parent[:, :, None]                             # (N, n, V, 3)
    d = np.where(absent[..., None], np.nan, direction[at, :, j[:, None]])
    bone = np.array([g[5] for g in group])
    r, std, _ = fit_gaps(known[:, :2], known[:, 2:], bone, np.array([g[6] for g in group]), BONE_SIGMA * bone,
                         prior, PRIOR_SIGMA_M * unit, o, d, sigma_ray, RAY_GATE_M * unit,
                         np.array([g[8] for g in group]), PRIOR_SEEN_WEIGHT)
    return rows, j, parent + r, std


def fill_occlusions(X: np.ndarray, instant: np.ndarray, track: np.ndarray, origin: np.ndarray,
                    direction: np.ndarray, prior_X: np.ndarray | None = None, long_gap: int = 5,
                    max_gap: int = 90, unit: float = 1.0, refused: np.ndarray | None = None,
                    root_gap: int = 0, sigma_ray: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fill the limb joints of tracked persons through runs of missing instants.

    Args:
        X: ``(Q, 17, 3)`` persons, NaN where a joint is missing; instant, track: ``(Q,)``.
        origin, direction: ``(Q, V, 17, 3)`` the rays of each person's 2D keypoints
            (:func:`rays`), NaN where a view has none.
        prior_X: ``(Q, 17, 3)`` the pose prior's guess of the missing joints (None: no prior);
            the fill follows its offset of a joint from the joint's parent, as guessed with it
            (a filled elbow is not where the prior put its own).
        long_gap: runs from this long, and those at a track's end, are flagged inferred;
            shorter ones interpolated. [instants]
        max_gap: the longest run filled. [instants]
        unit: world units per metre (the module's constants are in metres).
        refused: ``(Q, 17)`` joints of ``X`` refused as outliers (:mod:`mvm.rig.refusals`), filled as
            missing ones (those that cannot be are left missing); the rays of a run with one
            are tried against the track's motion first (``gate_sigmas`` of
            :func:`mvm.core.gap_fit.fit_gaps`).
        root_gap: the roots of the limbs (:data:`ROOT_JOINTS`) missing for up to this many
            instants are interpolated first (flagged interpolated, confidence 0, as the
            completion after the fill would leave them), so that the limbs hanging from them
            can be filled through the gap. [instants]
        sigma_ray: the standard deviation of a joint's distance to its rays (:func:`ray_sigma`);
            None: :data:`RAY_SIGMA_M`. [world units]
    Returns:
        ``(X: (Q, 17, 3), flags: (Q, 17) int8, confidence: (Q, 17))``: the flags of the filled
        joints (:data:`mvm.core.completion.INTERPOLATED` or ``INFERRED``; 0 elsewhere), their
        confidence (0 elsewhere).
    """
    X = np.array(X, dtype=float)
    refused = np.zeros(X.shape[:2], bool) if refused is None else np.asarray(refused, bool)
    X[refused] = np.nan
    instant, track = np.asarray(instant), np.asarray(track)
    flags = np.zeros(X.shape[:2], np.int8)
    confidence = np.zeros(X.shape[:2])
    if not len(X):
        return X, flags, confidence
    roots, root_flags = complete_tracks(X[:, ROOT_JOINTS], instant, track, root_gap)
    X[:, ROOT_JOINTS] = roots
    flags[:, ROOT_JOINTS] = np.where(root_flags == INTERPOLATED, INTERPOLATED, 0)
    series = track_rows(instant, track)
    sigma_ray = RAY_SIGMA_M * unit if sigma_ray is None else sigma_ray
    for joints in LIMB_PASSES:
        gaps = [g for index in series for g in _track_gaps(X, index, refused, joints, long_gap, max_gap, unit)]
        for n in sorted({len(g[0]) for g in gaps}):
            group = [g for g in gaps if len(g[0]) == n]
            rows, j, filled, std = _fill_group(X, group, origin, direction, prior_X, unit, sigma_ray)
            at = rows >= 0                                                         # a row at the instant
            k = np.nonzero(at)[0]                                                  # its gap
            X[rows[at], j[k]] = filled[at]
            flags[rows[at], j[k]] = np.array([g[7] for g in group])[k]
            confidence[rows[at], j[k]] = 1.0 / (1.0 + (std[at] / (CONFIDENCE_SCALE_M * unit)) ** 2)
    return X, flags, confidence
