"""What the report of a rig shows, computed from arrays: the detection behind every member of a
person, the reprojection error of every matched keypoint, its median per camera over time, the
runs of each track's joint flags and the joint angles along a track. Pure numpy, no I/O.

Axes: ``T`` instants, ``Q`` persons over all instants (a flat list, ``instant`` says when),
``V`` cameras, ``N`` 2D poses, ``J = 17`` joints, ``A`` joint angles, ``B`` time bins.
"""
from __future__ import annotations

import numpy as np

from mvm.core.completion import OBSERVED
from mvm.core.geometry import project
from mvm.core.joint_angles import angle_sources, flexion_angles


def member_detections(members: np.ndarray, instant: np.ndarray, det_instant: np.ndarray,
                      det_view: np.ndarray) -> np.ndarray:
    """The 2D pose behind every member: ``(Q, V)`` indices into the detections, -1 where none.

    ``members: (Q, V)`` the pose's index within its camera's frame (as ``poses3d.jsonl`` writes
    it: the order of the camera's input file), -1 where none; ``instant: (Q,)``;
    ``det_instant, det_view: (N,)`` of the detections. A member beyond the poses of its camera
    and instant is -1."""
    members = np.asarray(members, dtype=np.int64)
    Q, V = members.shape
    key = np.asarray(det_instant, dtype=np.int64) * V + np.asarray(det_view, dtype=np.int64)
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    wanted = np.asarray(instant, dtype=np.int64)[:, None] * V + np.arange(V)[None]          # (Q, V)
    start = np.searchsorted(sorted_key, wanted, side="left")
    stop = np.searchsorted(sorted_key, wanted, side="right")
    ok = (members >= 0) & (start + members < stop)
    out = np.full((Q, V), -1, dtype=np.int64)
    out[ok] = order[(start + members)[ok]]
    return out


def keypoint_errors(X: np.ndarray, flags: np.ndarray, detection: np.ndarray, keypoints: np.ndarray,
                    P: np.ndarray) -> np.ndarray:
    """Reprojection error of every matched 2D keypoint: ``(Q, V, J)`` px.

    ``X: (Q, J, 3)`` the persons' joints; ``flags: (Q, J)`` (:mod:`mvm.core.completion`): only
    observed joints count; ``detection: (Q, V)`` the 2D pose of each member
    (:func:`member_detections`); ``keypoints: (N, J, 3)`` undistorted pixels and confidence;
    ``P: (V, 3, 4)``. NaN where there is no member, the keypoint is missing (confidence 0), the
    joint is not observed or lies behind the camera."""
    X = np.asarray(X, dtype=float)
    Q, J = X.shape[:2]
    V = len(P)
    uv, depth = project(X[:, None], np.asarray(P, dtype=float)[None, :, None])              # (Q, V, J, 2)
    has = detection >= 0
    kp = np.asarray(keypoints, dtype=float)[np.maximum(detection, 0)] if len(keypoints) else np.zeros((Q, V, J, 3))
    error = np.linalg.norm(uv - kp[..., :2], axis=-1)
    ok = has[..., None] & (kp[..., 2] > 0) & (np.asarray(flags)[:, None, :] == OBSERVED) & (depth > 0) \
        & np.isfinite(error)
    return np.where(ok, error, np.nan).reshape(Q, V, J)


def grouped_quantile(values: np.ndarray, group: np.ndarray, groups: int,
                     q: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """The ``q`` quantile (linear interpolation, as :func:`numpy.quantile`) of the finite
    ``values: (n,)`` of each group ``group: (n,)`` in ``[0, groups)``: ``(groups,)`` (NaN for an
    empty group) and the count of each ``(groups,)``. One sort, no loop over groups."""
    values = np.asarray(values, dtype=float).reshape(-1)
    group = np.asarray(group, dtype=np.int64).reshape(-1)
    keep = np.isfinite(values)
    values, group = values[keep], group[keep]
    order = np.lexsort((values, group))
    values, group = values[order], group[order]
    count = np.bincount(group, minlength=groups)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    position = (count - 1) * q
    low = np.floor(position).astype(np.int64)
    high = np.ceil(position).astype(np.int64)
    out = np.full(groups, np.nan)
    has = count > 0
    a, b = values[(start + low)[has]], values[(start + high)[has]]
    out[has] = a + (b - a) * (position - low)[has]
    return out, count


def time_bins(T: int, max_bins: int) -> np.ndarray:
    """At most ``max_bins`` consecutive runs of the ``T`` instants, nearly equal:
    ``(B + 1,)`` boundaries (instant indices, the last ``T``); one bin per instant when ``T <= max_bins``."""
    B = max(1, min(T, max_bins))
    return np.unique(np.round(np.linspace(0, T, B + 1)).astype(np.int64))


def camera_error_series(errors: np.ndarray, instant: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The median reprojection error of each camera in each time bin.

    ``errors: (Q, V, J)`` (:func:`keypoint_errors`), ``instant: (Q,)``, ``bounds: (B + 1,)``
    (:func:`time_bins`) -> medians ``(B, V)`` px (NaN: no keypoint) and counts ``(B, V)``."""
    Q, V, J = errors.shape
    B = len(bounds) - 1
    b = np.searchsorted(bounds, np.asarray(instant, dtype=np.int64), side="right") - 1     # (Q,)
    group = np.broadcast_to((b[:, None] * V + np.arange(V))[:, :, None], (Q, V, J))
    median, count = grouped_quantile(errors, group, B * V)
    return median.reshape(B, V), count.reshape(B, V)


def camera_error_summary(errors: np.ndarray) -> dict:
    """Per camera over the whole capture: ``median``, ``p90`` ``(V,)`` px and ``count`` ``(V,)``
    of the matched keypoints' errors ``errors: (Q, V, J)``."""
    Q, V, J = errors.shape
    group = np.broadcast_to(np.arange(V)[None, :, None], (Q, V, J))
    median, count = grouped_quantile(errors, group, V)
    p90, _ = grouped_quantile(errors, group, V, 0.9)
    return {"median": median, "p90": p90, "count": count}


def flag_runs(flags: np.ndarray) -> np.ndarray:
    """Runs of equal flags along time of every joint: ``flags: (L, J)`` int (a track's instants)
    -> ``(R, 4)`` int rows ``(joint, start, stop, flag)``, ``stop`` excluded, in joint order."""
    flags = np.asarray(flags, dtype=np.int64)
    L, J = flags.shape
    if L == 0:
        return np.zeros((0, 4), dtype=np.int64)
    change = np.ones((L, J), dtype=bool)
    change[1:] = flags[1:] != flags[:-1]
    joint, start = np.nonzero(change.T)                                   # joint-major order
    stop = np.empty_like(start)
    stop[:-1] = start[1:]
    last = np.ones(len(start), dtype=bool)
    last[:-1] = joint[1:] != joint[:-1]
    stop[last] = L
    return np.stack([joint, start, stop, flags[start, joint]], axis=1)


def dense_track(values: np.ndarray, instant: np.ndarray, track: np.ndarray, track_id: int,
                fill=np.nan) -> tuple[np.ndarray, np.ndarray]:
    """One track's rows of ``values: (Q, ...)`` laid on its instants from first to last:
    ``(instants (L,), (L, ...))`` with ``fill`` where the track was not seen."""
    rows = np.flatnonzero(np.asarray(track) == track_id)
    t0, t1 = int(instant[rows].min()), int(instant[rows].max())
    values = np.asarray(values)
    out = np.full((t1 - t0 + 1,) + values.shape[1:], fill, dtype=np.result_type(values.dtype, np.asarray(fill)))
    out[instant[rows] - t0] = values[rows]
    return np.arange(t0, t1 + 1), out


def track_angles(X: np.ndarray, flags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The flexion angles (:func:`mvm.core.joint_angles.flexion_angles`) of persons ``X: (Q, J, 3)``
    with ``flags: (Q, J)``: degrees ``(Q, A)`` and the least-observed flag of each ``(Q, A)``
    (:func:`mvm.core.joint_angles.angle_sources`)."""
    return flexion_angles(X), angle_sources(flags)
