"""Synchronizing a rig's cameras from the people's motion (no I/O).

Each camera's *motion signal* is, at every frame, the mean speed of the people it sees: every
pose is linked to the nearest pose of the next frame (Hungarian assignment on the median
joint distance relative to the person's image size), and its speed is the median
displacement of its joints relative to that size (robust to a swapped or outlying joint;
relative, so near and far people count alike). A camera's offset to the reference camera is
the lag that maximizes the normalized cross-correlation of the two signals (as Pose2Sim
does). When the cameras are calibrated, the lags around the best correlation peaks are
scored by the triangulation error of the alignment they make — for every pose of the camera,
the smallest median Sampson error (the first-order reprojection error of the optimal two-view
triangulation) against the reference camera's poses of the aligned frame — and the lowest
error wins.

Convention (``sync.toml``, :mod:`mvm.io.sync_toml`): the offset of camera ``c`` is the
number of frames to ADD to its frame numbers to reach the reference camera's: its frame ``f``
shows the instant of the reference camera's frame ``f + offset``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

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
#: Sampson errors above this are clipped (a wrong pairing counts as this much). [px]
MAX_ERROR_PX = 30.0
#: Correlation peaks whose neighbourhoods are scored by the triangulation error, and the
#: neighbourhood's half-width. [-, frames]
REFINE_PEAKS = 3
REFINE_WINDOW = 3
#: With the triangulation error, a lag is ambiguous when another one, ``PEAK_SEPARATION``
#: frames away or more, has an error below this multiple of the best.
AMBIGUOUS_ERROR_RATIO = 1.25


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
    with np.errstate(invalid="ignore"), np.testing.suppress_warnings() as sup:
        sup.filter(RuntimeWarning)
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
        with np.testing.suppress_warnings() as sup:
            sup.filter(RuntimeWarning)
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
    t = t_b - R @ t_a
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return np.linalg.inv(K_b).T @ tx @ R @ np.linalg.inv(K_a)


def sampson_px(F: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Sampson error (pixels) of correspondences ``xa, xb: (..., 2)`` -> ``(...)``."""
    ha = np.concatenate([xa, np.ones(xa.shape[:-1] + (1,))], -1)
    hb = np.concatenate([xb, np.ones(xb.shape[:-1] + (1,))], -1)
    Fa = ha @ F.T
    Fb = hb @ F
    num = np.einsum("...i,...i->...", hb, Fa)
    den = Fa[..., 0] ** 2 + Fa[..., 1] ** 2 + Fb[..., 0] ** 2 + Fb[..., 1] ** 2
    return np.abs(num) / np.sqrt(np.maximum(den, 1e-18))


def alignment_error(F: np.ndarray, ref_kp: np.ndarray, ref_frame: np.ndarray, kp: np.ndarray, frame: np.ndarray,
                    lag: int) -> tuple[float, int]:
    """Triangulation error of aligning a camera's frame ``f`` with the reference's ``f + lag``.

    Args:
        F: ``(3, 3)`` reference -> camera fundamental matrix (:func:`fundamental_matrix`).
        ref_kp: ``(A, 17, 3)``, ref_frame: ``(A,)`` sorted; kp: ``(B, 17, 3)``, frame: ``(B,)``.
    Returns:
        ``(error, poses)``: the mean over the camera's poses that share an aligned frame of
        their smallest median Sampson error (px, clipped at ``MAX_ERROR_PX``), and their number.
    """
    target = frame + lag
    lo, hi = np.searchsorted(ref_frame, target), np.searchsorted(ref_frame, target, "right")
    counts = hi - lo
    if not counts.sum():
        return np.nan, 0
    b = np.repeat(np.arange(len(kp)), counts)
    a = np.repeat(lo, counts) + (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts))
    both = (ref_kp[a, :, 2] > 0) & (kp[b, :, 2] > 0)                                        # (M, 17)
    err = np.where(both, sampson_px(F, ref_kp[a, :, :2], kp[b, :, :2]), np.nan)
    with np.testing.suppress_warnings() as sup:
        sup.filter(RuntimeWarning)
        med = np.nanmedian(err, axis=1)
    med = np.where(both.sum(1) >= MIN_COMMON_JOINTS, np.minimum(med, MAX_ERROR_PX), MAX_ERROR_PX)
    best = np.full(len(kp), np.inf)
    np.minimum.at(best, b, med)
    best = best[np.isfinite(best)]
    return (float(best.mean()), len(best)) if len(best) else (np.nan, 0)


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


def synchronize(keypoints: np.ndarray, camera: np.ndarray, frame: np.ndarray, n_cameras: int, max_offset: int,
                fundamentals: list[np.ndarray | None] | None = None) -> SyncResult:
    """Each camera's offset to camera 0 (module docstring).

    Args:
        keypoints: ``(N, 17, 3)`` undistorted 2D poses of every camera; camera: ``(N,)``;
            frame: ``(N,)`` each pose's frame number *in its own camera*.
        max_offset: lags ``-max_offset .. max_offset`` are tried.
        fundamentals: per camera, the reference -> camera fundamental matrix (None: no
            calibration; the correlation alone decides).
    Returns:
        :class:`SyncResult`. A camera without poses raises ``ValueError`` naming its index.
    """
    lags = np.arange(-max_offset, max_offset + 1)
    signals, firsts = [], []
    for c in range(n_cameras):
        rows = camera == c
        if not rows.any():
            raise ValueError(f"camera {c}: no 2D poses")
        first = int(frame[rows].min())
        signals.append(motion_signal(keypoints[rows], frame[rows], first, int(frame[rows].max()) - first + 1))
        firsts.append(first)
    V, L = n_cameras, len(lags)
    correlation = np.full((V, L), np.nan)
    offsets, peak_lag = np.zeros(V, int), np.zeros(V, int)
    peak, error, ambiguous = np.ones(V), np.full(V, np.nan), np.zeros(V, bool)
    ref_rows = np.flatnonzero(camera == 0)
    ref_rows = ref_rows[np.argsort(frame[ref_rows], kind="stable")]
    for c in range(1, V):
        correlation[c] = cross_correlation(signals[0], signals[c], firsts[c] - firsts[0], lags)
        peaks = _peaks(correlation[c])
        if not len(peaks):
            raise ValueError(f"camera {c}: its people's motion overlaps the reference camera's in fewer than "
                             f"{MIN_OVERLAP_FRAMES} frames")
        top = peaks[0]
        peak[c], peak_lag[c] = correlation[c, top], lags[top]
        offsets[c] = lags[top]
        ambiguous[c] = peak[c] < MIN_PEAK or _is_ambiguous(top, correlation[c], lags, True, AMBIGUOUS_PEAK_RATIO)
        F = None if fundamentals is None else fundamentals[c]
        if F is None:
            continue
        rows = np.flatnonzero(camera == c)
        candidates = np.unique(np.clip(np.concatenate([np.arange(p - REFINE_WINDOW, p + REFINE_WINDOW + 1)
                                                       for p in peaks[:REFINE_PEAKS]]), 0, L - 1))
        scores = np.full(L, np.nan)
        for i in candidates:
            scores[i] = alignment_error(F, keypoints[ref_rows], frame[ref_rows], keypoints[rows], frame[rows],
                                        int(lags[i]))[0]
        if np.isfinite(scores).any():
            best = int(np.nanargmin(scores))
            offsets[c], error[c] = lags[best], scores[best]
            ambiguous[c] = _is_ambiguous(best, scores, lags, False, AMBIGUOUS_ERROR_RATIO)
    return SyncResult(offsets, peak, peak_lag, error, ambiguous, lags, correlation)
