"""Identities over time: each instant's persons linked to the previous ones by 3D distance
(Hungarian assignment), with track ids that survive short gaps; optional temporal smoothing.
Pure numpy/scipy, no I/O."""
from __future__ import annotations

import warnings

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.signal import butter, filtfilt, savgol_filter


def pose_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean joint distance over the joints both poses have. ``a: (P, J, 3)``, ``b: (Q, J, 3)`` ->
    ``(P, Q)`` (inf where no joint is shared)."""
    diff = np.linalg.norm(a[:, None] - b[None], axis=-1)                          # (P, Q, J)
    ok = np.isfinite(diff)
    count = ok.sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(ok, diff, 0.0).sum(-1) / count
    return np.where(count > 0, mean, np.inf)


def link_tracks(X: np.ndarray, instant: np.ndarray, max_distance: float, max_gap: int) -> np.ndarray:
    """Track id of every person.

    Args:
        X: ``(Q, J, 3)`` persons (NaN: missing joint); instant: ``(Q,)`` their instants (integers).
        max_distance: largest mean joint distance (world units) between a person and the last
            pose of the track it joins.
        max_gap: a track unseen for more than ``max_gap`` instants cannot be joined any more.
    Returns:
        ``(Q,)`` track ids 0, 1, … in order of first appearance.
    """
    X = np.asarray(X, dtype=float)
    instant = np.asarray(instant)
    track = np.full(len(X), -1)
    last_pose = np.zeros((0,) + X.shape[1:])
    last_seen = np.zeros(0, dtype=np.int64)
    for t in np.unique(instant):
        rows = np.flatnonzero(instant == t)
        alive = np.flatnonzero(t - last_seen <= max_gap + 1)
        assigned = np.full(len(rows), -1)
        if len(alive):
            cost = pose_distance(X[rows], last_pose[alive])
            feasible = cost <= max_distance
            r, c = linear_sum_assignment(np.where(feasible, cost, 1e12))
            ok = feasible[r, c]
            assigned[r[ok]] = alive[c[ok]]
        new = assigned < 0
        assigned[new] = len(last_seen) + np.arange(new.sum())
        last_pose = np.concatenate([last_pose, np.zeros((new.sum(),) + X.shape[1:])])
        last_seen = np.concatenate([last_seen, np.zeros(new.sum(), dtype=np.int64)])
        # Keep the last seen position of joints missing now.
        previous = last_pose[assigned]
        last_pose[assigned] = np.where(np.isfinite(X[rows]), X[rows], np.where(new[:, None, None], np.nan, previous))
        last_seen[assigned] = t
        track[rows] = assigned
    return track


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Contiguous True runs of a 1-D mask as ``[(start, stop)]``."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def smooth_series(points: np.ndarray, method: str, rate: float = 30.0, cutoff_hz: float = 6.0,
                  order: int = 4, window: int = 9) -> np.ndarray:
    """Smooth one track along time. ``points: (L, J, 3)`` consecutive instants (NaN: missing) ->
    ``(L, J, 3)``. Each joint's finite runs are filtered separately (zero-phase Butterworth
    low-pass, or Savitzky–Golay of degree 2); runs too short for the filter are left as they are."""
    if method == "none":
        return points.copy()
    if method not in ("butterworth", "savgol"):
        raise ValueError(f"smoothing: expected 'none', 'butterworth' or 'savgol', got {method!r}")
    out = np.array(points, dtype=float)
    if method == "butterworth":
        if not 0 < cutoff_hz < rate / 2:
            raise ValueError(f"cutoff_hz must be in (0, {rate / 2}) for a rate of {rate} Hz, got {cutoff_hz}")
        b, a = butter(order // 2 if order > 1 else 1, cutoff_hz / (rate / 2))   # filtfilt doubles the order
        min_length = 3 * max(len(a), len(b)) + 1
    else:
        window = window if window % 2 else window + 1
        min_length = window
    finite = np.isfinite(out).all(-1)                                                 # (L, J)
    for j in range(out.shape[1]):
        for start, stop in _runs(finite[:, j]):
            if stop - start < min_length:
                continue
            segment = out[start:stop, j]
            if method == "butterworth":
                out[start:stop, j] = filtfilt(b, a, segment, axis=0)
            else:
                out[start:stop, j] = savgol_filter(segment, window, 2, axis=0)
    return out


def track_series(X: np.ndarray, instant: np.ndarray, track: np.ndarray, track_id: int) -> tuple[np.ndarray, np.ndarray]:
    """One track as a dense series over its instants: ``(instants (L,), points (L, J, 3))`` with
    NaN rows where the track was not seen (``L`` spans its first to last instant)."""
    rows = np.flatnonzero(track == track_id)
    t0, t1 = int(instant[rows].min()), int(instant[rows].max())
    points = np.full((t1 - t0 + 1,) + X.shape[1:], np.nan)
    points[instant[rows] - t0] = X[rows]
    return np.arange(t0, t1 + 1), points


def smooth_tracks(X: np.ndarray, instant: np.ndarray, track: np.ndarray, method: str, **kwargs) -> np.ndarray:
    """:func:`smooth_series` applied to every track. ``X: (Q, J, 3)`` -> ``(Q, J, 3)``."""
    if method == "none":
        return np.array(X, dtype=float)
    out = np.array(X, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for k in np.unique(track):
            rows = np.flatnonzero(track == k)
            times, series = track_series(X, instant, track, k)
            smoothed = smooth_series(series, method, **kwargs)
            out[rows] = smoothed[instant[rows] - times[0]]
    return out
