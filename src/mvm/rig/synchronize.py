"""Synchronizing a rig's cameras from the people's motion (no I/O).

Each camera's *motion signal* is, at every frame, the mean speed of the people it sees: every
pose is linked to the nearest pose of the next frame (Hungarian assignment on the median
joint distance relative to the person's image size), and its speed is the median
displacement of its joints relative to that size, each joint's step capped (a jumping joint
is the detector's error). A camera's correlation with the reference camera is the normalized
cross-correlation of the two signals at every lag (as Pose2Sim does); its peak is reported.

On a rig of several people the signal depends much on the view (who hides whom, which limbs
move across the image), so the offset is decided by geometry: every lag is scored by the
triangulation error of the alignment it makes — for every pose of the camera, the smallest
mean Sampson error of its joints (each clipped: the moving joints carry the signal, a median
would keep the still ones) (the first-order reprojection error of the optimal two-view
triangulation) against the reference camera's poses of the aligned frame, clipped — and the
lowest error wins. The epipolar geometry comes from the calibration when the rig has one;
otherwise it is estimated from the people (:mod:`mvm.rig.calibrate`): roughly (a loose
threshold) at the correlation's best peaks and lag 0, the most consistent one kept; the lags
near the best one it gives are then each fitted with their own geometry, the one that fits its
alignment best gives the geometry every lag is scored with; when that leaves the offset
ambiguous, every lag is fitted with its own geometry (up to ``MAX_OWN_GEOMETRY_LAGS`` lags).

Convention (``sync.toml``, :mod:`mvm.io.sync_toml`): the offset of camera ``c`` is the
number of frames to ADD to its frame numbers to reach the reference camera's: its frame ``f``
shows the instant of the reference camera's frame ``f + offset``.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from mvm.core.camera import normalized_points
from mvm.core.geometry import skew
from mvm.rig.people_pairs import INLIER_PX, aligned_pairs, essential_from_pairings, sampson

#: Two poses of consecutive frames are one person when their median joint distance is below
#: this fraction of the person's image size. [1]
MAX_LINK_FRACTION = 0.3
#: A joint's step between two frames counts at most this fraction of the person's size (a
#: joint that jumps is the detector's error, not motion). [1]
MAX_JOINT_STEP = 0.1
#: Fewest joints two poses must share to be linked or compared.
MIN_COMMON_JOINTS = 6
#: A lag needs at least this many frames of both signals. [frames]
MIN_OVERLAP_FRAMES = 10
#: A correlation peak is ambiguous when another peak, at least ``PEAK_SEPARATION`` frames away,
#: reaches this fraction of it, or when the peak itself is below ``MIN_PEAK``.
AMBIGUOUS_PEAK_RATIO = 0.9
PEAK_SEPARATION = 3
MIN_PEAK = 0.3
#: A joint's Sampson error counts at most this much (an outlying joint), a pose's mean error at
#: most ``MAX_ERROR_PX`` (a wrong pairing). [px]
MAX_JOINT_ERROR_PX = 15.0
MAX_ERROR_PX = 30.0
#: Correlation peaks (with lag 0) at which the epipolar geometry is estimated when the rig is
#: not calibrated.
REFINE_PEAKS = 3
#: The first, rough epipolar geometry accepts joints this far from it (the candidate lag may be
#: a few frames off, and the people moved meanwhile); the lags within ``REFINE_WINDOW`` of the
#: best one it gives are then fitted each with its own geometry. [px, frames]
SEARCH_INLIER_PX = 25.0
REFINE_WINDOW = 2
#: When the offset found so is ambiguous, every lag is fitted with its own geometry, if there are
#: at most this many lags.
MAX_OWN_GEOMETRY_LAGS = 41
#: Frames used at most, and hypotheses drawn at most, to estimate an epipolar geometry.
ESTIMATE_FRAMES = 40
ESTIMATE_HYPOTHESES = 100
#: With the triangulation error, a lag is ambiguous when another one, ``PEAK_SEPARATION``
#: frames away or more, has an error below this multiple of the best.
AMBIGUOUS_ERROR_RATIO = 1.25


class SyncError(ValueError):
    """A camera cannot be synchronized: ``camera`` is its index."""

    def __init__(self, camera: int, problem: str):
        self.camera = camera
        self.problem = problem
        super().__init__(f"camera {camera}: {problem}")


@dataclass
class SyncResult:
    """Offsets of the ``V`` cameras to the reference camera (index 0).

    Attributes:
        offsets: ``(V,)`` int, frames to add to each camera's frame numbers (0 for the reference).
        peak: ``(V,)`` the cross-correlation at the best correlation lag (1 for the reference).
        peak_lag: ``(V,)`` int, that lag.
        error_px: ``(V,)`` triangulation error of the chosen alignment (NaN: not calibrated).
        ambiguous: ``(V,)`` bool, another lag is almost as good.
        lags: ``(L,)`` int, the lags tried; correlation: ``(V, L)`` (NaN: too little overlap).
    """

    offsets: np.ndarray
    peak: np.ndarray
    peak_lag: np.ndarray
    error_px: np.ndarray
    ambiguous: np.ndarray
    lags: np.ndarray
    correlation: np.ndarray


def _pose_scale(keypoints: np.ndarray) -> np.ndarray:
    """Image size of each pose: the diagonal of its present joints' box. ``(N, 17, 3)`` -> ``(N,)``."""
    present = keypoints[..., 2] > 0
    xy = np.where(present[..., None], keypoints[..., :2], np.nan)
    with warnings.catch_warnings():                                      # a pose without joints: NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        span = np.nanmax(xy, 1) - np.nanmin(xy, 1)
    return np.nan_to_num(np.linalg.norm(span, axis=-1), nan=0.0)


def motion_signal(keypoints: np.ndarray, frame: np.ndarray, first: int, count: int) -> np.ndarray:
    """The motion signal of one camera (module docstring) over frames ``first .. first + count - 1``.

    Args:
        keypoints: ``(N, 17, 3)`` the camera's 2D poses (pixels, confidence; 0: missing).
        frame: ``(N,)`` their frame numbers.
    Returns:
        ``(count,)`` the mean relative speed of the people linked from each frame to the next
        (NaN where none is).
    """
    signal = np.full(count, np.nan)
    scale = _pose_scale(keypoints)
    order = np.argsort(frame, kind="stable")
    frames_sorted = frame[order]
    present = keypoints[..., 2] > 0
    for k in range(count - 1):
        f = first + k
        a = order[np.searchsorted(frames_sorted, f):np.searchsorted(frames_sorted, f, "right")]
        b = order[np.searchsorted(frames_sorted, f + 1):np.searchsorted(frames_sorted, f + 1, "right")]
        if not len(a) or not len(b):
            continue
        both = present[a][:, None] & present[b][None]                                        # (A, B, 17)
        step = np.linalg.norm(keypoints[a][:, None, :, :2] - keypoints[b][None, :, :, :2], axis=-1)
        size = np.maximum(np.maximum(scale[a][:, None], scale[b][None]), 1e-9)
        rel = np.where(both, step, np.nan) / size[..., None]
        with warnings.catch_warnings():                                  # no common joint: NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            cost = np.nanmedian(rel, axis=-1)
        cost = np.where(both.sum(-1) >= MIN_COMMON_JOINTS, cost, np.inf)
        finite = np.where(np.isfinite(cost), cost, 1e6)
        rows, cols = linear_sum_assignment(finite)
        keep = cost[rows, cols] < MAX_LINK_FRACTION
        if keep.any():
            speed = np.nanmean(np.minimum(rel[rows[keep], cols[keep]], MAX_JOINT_STEP), axis=-1)
            signal[k] = speed.mean()
    return signal


def cross_correlation(reference: np.ndarray, other: np.ndarray, offset0: int, lags: np.ndarray,
                      min_overlap: int = MIN_OVERLAP_FRAMES) -> np.ndarray:
    """Normalized cross-correlation of two signals at ``lags``.

    Args:
        reference: ``(A,)`` the reference signal (its frame ``first_ref + i``); other: ``(B,)``
            (its frame ``first_other + j``); ``offset0 = first_other - first_ref``.
        lags: ``(L,)`` int: ``other``'s frame ``f`` aligned with ``reference``'s ``f + lag``.
    Returns:
        ``(L,)`` Pearson correlation over the frames where both are known (NaN: fewer than
        ``min_overlap`` such frames).
    """
    out = np.full(len(lags), np.nan)
    for n, lag in enumerate(lags):
        shift = offset0 + lag                              # other's index j -> reference index j + shift
        j0, j1 = max(0, -shift), min(len(other), len(reference) - shift)
        if j1 - j0 < min_overlap:
            continue
        a, b = reference[j0 + shift:j1 + shift], other[j0:j1]
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() < min_overlap:
            continue
        a, b = a[ok] - a[ok].mean(), b[ok] - b[ok].mean()
        denominator = np.sqrt((a * a).sum() * (b * b).sum())
        out[n] = (a * b).sum() / denominator if denominator > 0 else np.nan
    return out


def fundamental_matrix(K_a: np.ndarray, R_a: np.ndarray, t_a: np.ndarray,
                       K_b: np.ndarray, R_b: np.ndarray, t_b: np.ndarray) -> np.ndarray:
    """``F`` with ``x_b^T F x_a = 0`` for pixels of the same point in cameras a and b: ``(3, 3)``."""
    R = R_b @ R_a.T
    return essential_to_fundamental(skew(t_b - R @ t_a) @ R, K_a, K_b)


def essential_to_fundamental(E: np.ndarray, K_a: np.ndarray, K_b: np.ndarray) -> np.ndarray:
    """``K_b^-T E K_a^-1``: ``(3, 3)``."""
    return np.linalg.inv(K_b).T @ E @ np.linalg.inv(K_a)


def alignment_error(F: np.ndarray, ref_kp: np.ndarray, ref_frame: np.ndarray, kp: np.ndarray, frame: np.ndarray,
                    lag: int) -> float:
    """Triangulation error of aligning a camera's frame ``f`` with the reference's ``f + lag``.

    Args:
        F: ``(3, 3)`` reference -> camera fundamental matrix (:func:`fundamental_matrix`).
        ref_kp: ``(A, 17, 3)``, ref_frame: ``(A,)``; kp: ``(B, 17, 3)``, frame: ``(B,)``.
    Returns:
        The mean over the camera's poses that share an aligned frame of their smallest mean
        Sampson error (px, clipped at ``MAX_ERROR_PX``); NaN when none does.
    """
    a, b = aligned_pairs(ref_frame, frame, lag)
    if not len(a):
        return np.nan
    both = (ref_kp[a, :, 2] > 0) & (kp[b, :, 2] > 0)                                        # (M, 17)
    err = np.minimum(sampson(F, ref_kp[a, :, :2], kp[b, :, :2]), MAX_JOINT_ERROR_PX)
    med = (err * both).sum(1) / np.maximum(both.sum(1), 1)
    med = np.where(both.sum(1) >= MIN_COMMON_JOINTS, np.minimum(med, MAX_ERROR_PX), MAX_ERROR_PX)
    best = np.full(len(kp), np.inf)
    np.minimum.at(best, b, med)
    best = best[np.isfinite(best)]
    return float(best.mean()) if len(best) else np.nan


def estimated_fundamental(ref_kp: np.ndarray, ref_frame: np.ndarray, kp: np.ndarray, frame: np.ndarray,
                          K_ref: np.ndarray, K: np.ndarray, lag: int, rng: np.random.Generator,
                          threshold_px: float = INLIER_PX) -> tuple[np.ndarray | None, int]:
    """The fundamental matrix of the people's poses aligned at ``lag``
    (:func:`mvm.rig.people_pairs.essential_from_pairings` on at most ``ESTIMATE_FRAMES`` frames):
    ``(F or None, joints it explains)``."""
    frames = np.unique(frame)
    if len(frames) > ESTIMATE_FRAMES:
        chosen = frames[np.linspace(0, len(frames) - 1, ESTIMATE_FRAMES).round().astype(int)]
        rows = np.flatnonzero(np.isin(frame, chosen))
    else:
        rows = np.arange(len(frame))
    a, b = aligned_pairs(ref_frame, frame[rows], lag)
    b = rows[b]
    ok = (ref_kp[a, :, 2] > 0) & (kp[b, :, 2] > 0)
    focal = np.sqrt(0.5 * (K_ref[0, 0] + K_ref[1, 1]) * 0.5 * (K[0, 0] + K[1, 1]))
    found = essential_from_pairings(normalized_points(ref_kp[a], K_ref), normalized_points(kp[b], K), ok,
                                    threshold_px / focal, rng, ESTIMATE_HYPOTHESES)
    if found is None:
        return None, 0
    E, _, inlier = found
    return essential_to_fundamental(E, K_ref, K), int(inlier.sum())


def _peaks(values: np.ndarray) -> np.ndarray:
    """Indices of the local maxima of ``values: (L,)`` (NaN never), best first."""
    v = np.where(np.isfinite(values), values, -np.inf)
    left = np.concatenate([[-np.inf], v[:-1]])
    right = np.concatenate([v[1:], [-np.inf]])
    index = np.flatnonzero((v >= left) & (v >= right) & np.isfinite(v))
    return index[np.argsort(-v[index], kind="stable")]


def _is_ambiguous(best: int, score: np.ndarray, lags: np.ndarray, better_high: bool, ratio: float) -> bool:
    """Another lag ``PEAK_SEPARATION`` or more frames from ``lags[best]`` scores within ``ratio``."""
    far = np.abs(lags - lags[best]) >= PEAK_SEPARATION
    other = score[far & np.isfinite(score)]
    if not len(other):
        return False
    return bool(other.max() >= ratio * score[best]) if better_high else bool(other.min() <= ratio * score[best])


def _scores(F: np.ndarray, pair: tuple, lags: np.ndarray) -> np.ndarray:
    """:func:`alignment_error` of ``pair = (ref_kp, ref_frame, kp, frame)`` at every lag: ``(L,)``."""
    return np.array([alignment_error(F, *pair, int(lag)) for lag in lags])


def _own_geometry(pair: tuple, K_ref: np.ndarray, K: np.ndarray, lags: np.ndarray, rng: np.random.Generator
                  ) -> tuple[list, np.ndarray]:
    """Each lag of ``lags`` fitted with its own epipolar geometry (:func:`estimated_fundamental`):
    ``(the fundamental matrices (None: not found), their alignment errors (L,))``."""
    fits = [estimated_fundamental(*pair, K_ref, K, int(lag), rng)[0] for lag in lags]
    return fits, np.array([alignment_error(f, *pair, int(lag)) if f is not None else np.nan
                           for f, lag in zip(fits, lags)])


def synchronize(keypoints: np.ndarray, camera: np.ndarray, frame: np.ndarray, K: np.ndarray, max_offset: int,
                fundamentals: list[np.ndarray | None] | None = None, seed: int = 0) -> SyncResult:
    """Each camera's offset to camera 0 (module docstring).

    Args:
        keypoints: ``(N, 17, 3)`` undistorted 2D poses of every camera; camera: ``(N,)``;
            frame: ``(N,)`` each pose's frame number *in its own camera*.
        K: ``(V, 3, 3)`` intrinsics.
        max_offset: lags ``-max_offset .. max_offset`` are tried.
        fundamentals: per camera, the reference -> camera fundamental matrix of a calibration
            (None: estimated from the people).
    Returns:
        :class:`SyncResult`. A camera without poses, or whose poses do not overlap the
        reference camera's, raises :class:`SyncError` naming its index.
    """
    rng = np.random.default_rng(seed)
    V = len(K)
    lags = np.arange(-max_offset, max_offset + 1)
    signals, firsts = [], []
    for c in range(V):
        rows = camera == c
        if not rows.any():
            raise SyncError(c, "no 2D poses")
        first = int(frame[rows].min())
        signals.append(motion_signal(keypoints[rows], frame[rows], first, int(frame[rows].max()) - first + 1))
        firsts.append(first)
    L = len(lags)
    correlation = np.full((V, L), np.nan)
    offsets, peak_lag = np.zeros(V, int), np.zeros(V, int)
    peak, error, ambiguous = np.ones(V), np.full(V, np.nan), np.zeros(V, bool)
    ref = np.flatnonzero(camera == 0)
    ref_kp, ref_frame = keypoints[ref], frame[ref]
    for c in range(1, V):
        correlation[c] = cross_correlation(signals[0], signals[c], firsts[c] - firsts[0], lags)
        peaks = _peaks(correlation[c])
        if not len(peaks):
            raise SyncError(c, f"its people's motion overlaps the reference camera's in fewer than "
                               f"{MIN_OVERLAP_FRAMES} frames at every offset up to {max_offset}")
        peak[c], peak_lag[c] = correlation[c, peaks[0]], lags[peaks[0]]
        rows = np.flatnonzero(camera == c)
        kp, fr = keypoints[rows], frame[rows]
        pair = (ref_kp, ref_frame, kp, fr)

        F = None if fundamentals is None else fundamentals[c]
        estimated = F is None
        if estimated:                          # a rough epipolar geometry at the most consistent candidate lag
            candidates = list(dict.fromkeys([int(lags[p]) for p in peaks[:REFINE_PEAKS]] + [0]))
            F = max((estimated_fundamental(ref_kp, ref_frame, kp, fr, K[0], K[c], lag, rng, SEARCH_INLIER_PX)
                     for lag in candidates), key=lambda found: found[1])[0]
            if F is not None:                  # then the lags near the best, each with its own geometry
                near = lags[int(np.nanargmin(_scores(F, pair, lags)))] + np.arange(-REFINE_WINDOW, REFINE_WINDOW + 1)
                near = near[np.isin(near, lags)]
                fits, own = _own_geometry(pair, K[0], K[c], near, rng)
                if np.isfinite(own).any():
                    F = fits[int(np.nanargmin(own))]
        if F is None:
            offsets[c] = peak_lag[c]
            ambiguous[c] = peak[c] < MIN_PEAK or _is_ambiguous(peaks[0], correlation[c], lags, True,
                                                                AMBIGUOUS_PEAK_RATIO)
            continue
        scores = _scores(F, pair, lags)
        if not np.isfinite(scores).any():
            raise SyncError(c, "shares no people with the reference camera at any offset")
        best = int(np.nanargmin(scores))
        ambiguous[c] = _is_ambiguous(best, scores, lags, False, AMBIGUOUS_ERROR_RATIO)
        if estimated and ambiguous[c] and len(lags) <= MAX_OWN_GEOMETRY_LAGS:   # every lag with its own geometry
            _, scores = _own_geometry(pair, K[0], K[c], lags, rng)
            if np.isfinite(scores).any():
                best = int(np.nanargmin(scores))
                ambiguous[c] = _is_ambiguous(best, scores, lags, False, AMBIGUOUS_ERROR_RATIO)
        offsets[c], error[c] = lags[best], scores[best]
    return SyncResult(offsets, peak, peak_lag, error, ambiguous, lags, correlation)
