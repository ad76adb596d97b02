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
    ok = (members >= 0) & (members < stop - start)                                    # no overflow
    out = np.full((Q, V), -1, dtype=np.int64)
    out[ok] = order[(start + members)[ok]]
    return out


def keypoint_errors(X: np.ndarray, flags: np.ndarray, detection: np.ndarray, keypoints: np.ndarray,
                    P: np.ndarray, block: int = 4096) -> np.ndarray:
    """Reprojection error of every matched 2D keypoint: ``(Q, V, J)`` px.

    ``X: (Q, J, 3)`` the persons' joints; ``flags: (Q, J)`` (:mod:`mvm.core.completion`): only
    observed joints count; ``detection: (Q, V)`` the 2D pose of each member
    (:func:`member_detections`); ``keypoints: (N, J, 3)`` undistorted pixels and confidence;
    ``P: (V, 3, 4)``. NaN where there is no member, the keypoint is missing (confidence 0), the
    joint is not observed or lies behind the camera. Computed ``block`` persons at a time (the
    memory of a long capture stays bounded)."""
    X = np.asarray(X, dtype=float)
    Q, J = X.shape[:2]
    P = np.asarray(P, dtype=float)
    keypoints = np.asarray(keypoints, dtype=float)
    out = np.full((Q, len(P), J), np.nan)
    for start in range(0, Q, block):
        rows = slice(start, start + block)
        uv, depth = project(X[rows, None], P)                                                # (b, V, J, 2)
        has = detection[rows] >= 0
        kp = keypoints[np.maximum(detection[rows], 0)] if len(keypoints) else np.zeros(uv.shape[:-1] + (3,))
        error = np.linalg.norm(uv - kp[..., :2], axis=-1)
        ok = has[..., None] & (kp[..., 2] > 0) & (np.asarray(flags[rows])[:, None, :] == OBSERVED) & (depth > 0) \
            & np.isfinite(error)
        out[rows] = np.where(ok, error, np.nan)
    return out


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


def truth_at_frames(frames: np.ndarray, instants: np.ndarray, poses3d: np.ndarray, offset: int) -> np.ndarray:
    """The true joints at each reconstructed instant: ``frames: (T,)`` (the reference camera's
    numbers), whose frame ``f`` shows the scene's instant ``f + offset``; ``instants: (S,)`` and
    ``poses3d: (S, G, J, 3)`` the truth -> ``(T, G, J, 3)``, NaN where the scene has no instant."""
    instants = np.asarray(instants, dtype=np.int64)
    wanted = np.asarray(frames, dtype=np.int64) + int(offset)
    at = np.minimum(np.searchsorted(instants, wanted), len(instants) - 1)
    found = instants[at] == wanted
    out = np.full((len(wanted),) + poses3d.shape[1:], np.nan)
    out[found] = poses3d[at[found]]
    return out


def match_tracks(X: np.ndarray, instant: np.ndarray, rank: np.ndarray, K: int,
                 truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each track's true person: the one closest on average over the track's joints and instants.

    ``X: (Q, J, 3)`` in the truth's frame, ``instant: (Q,)``, ``rank: (Q,)`` the track of each
    person in ``[0, K)``, ``truth: (T, G, J, 3)`` (:func:`truth_at_frames`) -> ``truth_of: (K,)``
    (-1: no true person near) and ``errors: (Q, J)`` each joint's distance to its track's true
    person (NaN where either is missing)."""
    Q, J = X.shape[:2]
    G = truth.shape[1]
    d = np.linalg.norm(X[:, None] - truth[instant], axis=-1)                               # (Q, G, J)
    ok = np.isfinite(d)
    sums = np.zeros((K, G))
    counts = np.zeros((K, G))
    np.add.at(sums, rank, np.where(ok, d, 0.0).sum(-1))
    np.add.at(counts, rank, ok.sum(-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(counts > 0, sums / counts, np.inf)
    truth_of = np.where(np.isfinite(mean).any(1), np.argmin(mean, axis=1), -1) if G else np.full(K, -1)
    errors = np.full((Q, J), np.nan)
    has = truth_of[rank] >= 0 if Q else np.zeros(0, bool)
    errors[has] = d[np.flatnonzero(has), truth_of[rank[has]]]
    return truth_of, errors


def compare_with_truth(X: np.ndarray, flags: np.ndarray, instant: np.ndarray, rank: np.ndarray, K: int,
                       centers: np.ndarray, true_centers: np.ndarray, truth: np.ndarray) -> dict | None:
    """The reconstruction against a simulated rig's truth, in the truth's frame.

    The estimate is moved by the similarity that maps the estimated camera centres onto the true
    ones (the identity when they agree within a millimetre, as with the true calibration; a
    calibration from the people has its own frame). ``X: (Q, J, 3)``, ``flags: (Q, J)``,
    ``instant, rank: (Q,)`` (tracks in ``[0, K)``), ``centers, true_centers: (V, 3)``,
    ``truth: (T, G, J, 3)`` (:func:`truth_at_frames`). Returns None with fewer than 3 cameras
    that do not already agree (no similarity), else ``scale``, ``R``, ``t`` (truth = s R x + t),
    ``camera_residual (V,)`` m, ``truth_of (K,)``, ``errors (Q, J)`` m, ``track_mpjpe (K,)``
    (observed joints), ``mpjpe`` {flag name: m} over observed / interpolated / inferred joints,
    ``angle_error (Q, A)`` degrees and ``track_angle_error (K,)`` (median over observed angles).
    """
    from mvm.core.completion import FLAG_NAMES, INFERRED, INTERPOLATED
    from mvm.core.geometry import similarity_transform

    centers, true_centers = np.asarray(centers, dtype=float), np.asarray(true_centers, dtype=float)
    if np.abs(centers - true_centers).max() < 1e-3:
        s, R, t = 1.0, np.eye(3), np.zeros(3)
    elif len(centers) >= 3:
        s, R, t = similarity_transform(centers, true_centers)
    else:
        return None
    aligned = s * np.asarray(X, dtype=float) @ R.T + t
    truth_of, errors = match_tracks(aligned, instant, rank, K, truth)
    observed = np.asarray(flags) == OBSERVED
    mpjpe = {FLAG_NAMES[f]: _mean(errors[np.asarray(flags) == f]) for f in (OBSERVED, INTERPOLATED, INFERRED)}
    sums = np.bincount(rank, np.where(observed & np.isfinite(errors), errors, 0.0).sum(1), minlength=K)
    counts = np.bincount(rank, (observed & np.isfinite(errors)).sum(1), minlength=K)
    has = truth_of[rank] >= 0
    true_pose = np.full(np.shape(X), np.nan)
    true_pose[has] = truth[instant[has], truth_of[rank[has]]]
    angles, sources = track_angles(X, flags)
    angle_error = np.abs(angles - flexion_angles(true_pose))
    track_angle, _ = grouped_quantile(np.where(sources == OBSERVED, angle_error, np.nan),
                                      np.broadcast_to(rank[:, None], angle_error.shape), K)
    with np.errstate(invalid="ignore", divide="ignore"):
        track_mpjpe = np.where(counts > 0, sums / counts, np.nan)
    return {"scale": float(s), "R": R, "t": t, "truth_of": truth_of, "errors": errors, "mpjpe": mpjpe,
            "camera_residual": np.linalg.norm(s * centers @ R.T + t - true_centers, axis=1),
            "track_mpjpe": track_mpjpe, "angle_error": angle_error, "track_angle_error": track_angle}


def _mean(values: np.ndarray) -> float:
    values = values[np.isfinite(values)]
    return float(values.mean()) if len(values) else float("nan")
