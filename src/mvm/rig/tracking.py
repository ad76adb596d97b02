"""Identities over time: each instant's persons linked to the previous ones by 3D distance
(Hungarian assignment), with track ids that survive short gaps; optional temporal smoothing.
Pure numpy, no I/O."""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from mvm.core.assignment import min_cost_assignment
from mvm.core.completion import take_rows, track_rows
from mvm.core.config import DEFAULT_FRAME_RATE_HZ
from mvm.rig.filters import butter_lowpass, filtfilt_many
from mvm.rig.instants import InstantPersons


def pose_distance(a: np.ndarray, b: np.ndarray, min_joints: int | np.ndarray = 1) -> np.ndarray:
    """Mean joint distance over the joints both poses have. ``a: (P, J, 3)``, ``b: (Q, J, 3)`` ->
    ``(P, Q)``; inf where fewer than ``min_joints`` (an int, or ``(P,)``) joints are shared (a
    mean over one or two joints says little about who a person is)."""
    diff = np.linalg.norm(a[:, None] - b[None], axis=-1)                          # (P, Q, J)
    ok = np.isfinite(diff)
    count = ok.sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(ok, diff, 0.0).sum(-1) / count
    need = np.maximum(np.asarray(min_joints), 1)
    return np.where(count >= (need[:, None] if need.ndim else need), mean, np.inf)


def assign(cost: np.ndarray, feasible: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The minimum-cost assignment of rows to columns among the ``feasible`` pairs (Hungarian):
    ``cost, feasible: (R, C)`` -> the rows and columns ``(K,), (K,)`` of the pairs kept, as many
    as can be, then the cheapest (:func:`mvm.core.assignment.min_cost_assignment` of the rows
    that have a feasible column)."""
    rows = np.flatnonzero(feasible.any(1))
    r, c = min_cost_assignment(np.where(feasible, cost, 1e12)[rows])
    ok = feasible[rows[r], c]
    return rows[r][ok], c[ok]


@dataclass
class Tracking:
    """Track ids and what the linking did. ``track: (Q,)`` ids 0, 1, … in order of first
    appearance; ``resumed``: links made across at least one instant where the track was unseen;
    ``unlinked``: persons that could have joined a live track by distance but shared too few
    joints with it (they start a new track)."""

    track: np.ndarray
    resumed: int = 0
    unlinked: int = 0

    @property
    def tracks(self) -> int:
        return int(len(np.unique(self.track)))


def link_tracks(X: np.ndarray, instant: np.ndarray, max_distance: float, max_gap: int,
                min_joints: int = 4, velocity_weight: float = 0.5) -> np.ndarray:
    """Track id of every person (see :func:`track_persons`). ``X: (Q, J, 3)`` -> ``(Q,)``."""
    return track_persons(X, instant, max_distance, max_gap, min_joints, velocity_weight).track


def track_persons(X: np.ndarray, instant: np.ndarray, max_distance: float, max_gap: int,
                  min_joints: int = 4, velocity_weight: float = 0.5) -> Tracking:
    """Link each instant's persons to the live tracks (Hungarian assignment on 3D distance).

    Each track keeps the last seen position of every joint and a velocity of its body (the mean
    displacement of its shared joints, smoothed); a person is compared with the track's pose
    *predicted* at the person's instant, so a track survives a loss of up to ``max_gap`` instants
    while its person walks on, and two people crossing close are told apart by where each was
    heading.

    Args:
        X: ``(Q, J, 3)`` persons (NaN: missing joint); instant: ``(Q,)`` their instants (integers).
        max_distance: largest mean joint distance (world units) between a person and the
            prediction of the track it joins.
        max_gap: a track unseen for more than ``max_gap`` instants cannot be joined any more.
        min_joints: the distance is only trusted over at least this many shared joints (fewer
            if the person has fewer).
        velocity_weight: weight of the newest displacement in the track's velocity (0: no motion
            model, 1: the last displacement only).
    Returns:
        :class:`Tracking`.
    """
    X = np.asarray(X, dtype=float)
    instant = np.asarray(instant)
    J = X.shape[1] if X.ndim == 3 else 17
    track = np.full(len(X), -1)
    last_pose = np.zeros((0, J, 3))
    velocity = np.zeros((0, 3))
    last_seen = np.zeros(0, dtype=np.int64)
    resumed = unlinked = 0
    present_count = np.isfinite(X).all(-1).sum(-1) if len(X) else np.zeros(0, int)
    order = np.argsort(instant, kind="stable")
    times, starts = np.unique(instant[order], return_index=True)
    for t, rows in zip(times.tolist(), np.split(order, starts[1:])):
        alive = np.flatnonzero(t - last_seen <= max_gap + 1)
        assigned = np.full(len(rows), -1)
        if len(alive):
            dt = (t - last_seen[alive]).astype(float)
            predicted = last_pose[alive] + (velocity[alive] * dt[:, None])[:, None, :]
            need = np.minimum(min_joints, present_count[rows])                         # (R,)
            cost = pose_distance(X[rows], predicted, need)
            feasible = cost <= max_distance
            r, c = assign(cost, feasible)
            assigned[r] = alive[c]
            resumed += int((dt[c] > 1).sum())
            alone = ~feasible.any(1)
            if alone.any():
                loose = pose_distance(X[rows[alone]], predicted, 1) <= max_distance
                unlinked += int(loose.any(1).sum())
        new = assigned < 0
        count_new = int(new.sum())
        if count_new:
            assigned[new] = len(last_seen) + np.arange(count_new)
            last_pose = np.concatenate([last_pose, np.full((count_new, J, 3), np.nan)])
            velocity = np.concatenate([velocity, np.zeros((count_new, 3))])
            last_seen = np.concatenate([last_seen, np.full(count_new, t, dtype=np.int64)])
        previous = last_pose[assigned]
        step = X[rows] - previous                                                      # (R, J, 3)
        shared = np.isfinite(step).all(-1)
        with np.errstate(invalid="ignore"):
            move = np.where(shared[..., None], step, 0).sum(1) / np.maximum(shared.sum(1), 1)[:, None]
        dt = np.maximum(t - last_seen[assigned], 1)[:, None]
        seen_before = ~new & (shared.sum(1) >= 1)
        velocity[assigned] = np.where(seen_before[:, None],
                                      (1 - velocity_weight) * velocity[assigned] + velocity_weight * move / dt,
                                      velocity[assigned])
        # Keep the last seen position of joints missing now.
        last_pose[assigned] = np.where(np.isfinite(X[rows]), X[rows], previous)
        last_seen[assigned] = t
        track[rows] = assigned
    return Tracking(track, resumed, unlinked)


def identity_switches(track: np.ndarray, truth: np.ndarray, instant: np.ndarray) -> dict:
    """Identity errors of ``track: (Q,)`` against the true identity ``truth: (Q,)`` of each
    person (-1: a person matching no true one), over ``instant: (Q,)``.

    Returns ``{"switches": times a true person's track id differs from its previous one (CLEAR-MOT
    ID switches), "tracks_per_person": mean number of track ids per true person, "persons": true
    persons seen}``.
    """
    track, truth, instant = (np.asarray(a) for a in (track, truth, instant))
    keep = truth >= 0
    track, truth, instant = track[keep], truth[keep], instant[keep]
    order = np.lexsort((instant, truth))
    same = truth[order][1:] == truth[order][:-1]
    switches = int((same & (track[order][1:] != track[order][:-1])).sum())
    people = np.unique(truth)
    per_person = [len(np.unique(track[truth == g])) for g in people]
    return {"switches": switches, "tracks_per_person": float(np.mean(per_person)) if per_person else float("nan"),
            "persons": int(len(people))}


def runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and stop (exclusive) of the runs of True of a 1-D ``mask``.

    >>> [a.tolist() for a in runs(np.array([1, 1, 0, 1], bool))]
    [[0, 3], [2, 4]]
    """
    edges = np.diff(np.concatenate([[0], np.asarray(mask).astype(np.int8), [0]]))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def smooth_series(points: np.ndarray, method: str, rate: float = DEFAULT_FRAME_RATE_HZ, cutoff_hz: float = 6.0,
                  order: int = 4, window: int = 9) -> np.ndarray:
    """Smooth one track along time. ``points: (L, J, 3)`` consecutive instants (NaN: missing) ->
    ``(L, J, 3)``. Each joint's finite runs are filtered separately (zero-phase Butterworth
    low-pass, or Savitzky–Golay of degree 2); runs too short for the filter are left as they are."""
    return _smooth_many([points], method, rate, cutoff_hz, order, window)[0]


def butterworth_order(order: int) -> int:
    """The order of the Butterworth designed for a zero-phase ``order`` (filtfilt doubles it)."""
    return order // 2 if order > 1 else 1


def _smooth_many(series: list, method: str, rate: float = DEFAULT_FRAME_RATE_HZ, cutoff_hz: float = 6.0,
                 order: int = 4, window: int = 9) -> list:
    """:func:`smooth_series` of every ``(L_i, J, 3)`` array of ``series``; the Butterworth
    filters every run (of any joint, any series) in one pass (:func:`mvm.rig.filters.filtfilt_many`)."""
    if method == "none":
        return [np.array(points, dtype=float) for points in series]
    if method not in ("butterworth", "savgol"):
        raise ValueError(f"smoothing: expected 'none', 'butterworth' or 'savgol', got {method!r}")
    if method == "butterworth":
        if not 0 < cutoff_hz < rate / 2:
            raise ValueError(f"cutoff_hz must be in (0, {rate / 2}) for a rate of {rate} Hz, got {cutoff_hz}")
        b, a = butter_lowpass(butterworth_order(order), cutoff_hz / (rate / 2))
        min_length = 3 * max(len(a), len(b)) + 1
    else:
        from scipy.signal import savgol_filter

        window = window if window % 2 else window + 1
        min_length = window
    out = [np.array(points, dtype=float) for points in series]
    found = []                                                                       # (series, joint, start, stop)
    for i, points in enumerate(out):
        finite = np.isfinite(points).all(-1)                                          # (L, J)
        for j in range(points.shape[1]):
            found += [(i, j, start, stop) for start, stop in zip(*runs(finite[:, j])) if stop - start >= min_length]
    if method == "butterworth":
        smoothed = filtfilt_many(b, a, [out[i][start:stop, j] for i, j, start, stop in found])
    else:
        smoothed = [savgol_filter(out[i][start:stop, j], window, 2, axis=0) for i, j, start, stop in found]
    for (i, j, start, stop), values in zip(found, smoothed):
        out[i][start:stop, j] = values
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
    if not len(out):
        return out
    index = track_rows(np.asarray(instant), np.asarray(track))
    series = [take_rows(out, rows) for rows in index]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        smoothed = _smooth_many(series, method, **kwargs)
    for rows, points in zip(index, smoothed):
        out[rows[rows >= 0]] = points[rows >= 0]
    return out


def with_missed_instants(persons: InstantPersons, track: np.ndarray) -> tuple[InstantPersons, np.ndarray, np.ndarray]:
    """``persons`` with a row for every instant between a track's first and last where the
    track has none (a person the instant's reconstruction missed whole, whom the track resumed
    after): no joint, no member, no keypoint, for the completion to fill. Rows stay sorted by
    instant (the new ones after those of their instant). ``track: (Q,)`` -> ``(persons, track:
    (Q',), added: (Q',) bool)``.

    >>> p = InstantPersons(np.zeros((3, 17, 3)), np.array([0, 0, 2]), np.ones((3, 17)), np.zeros((3, 1), int),
    ...                    np.ones((3, 1, 17), bool), np.ones((3, 1, 17), bool), np.zeros((3, 1, 17)), np.zeros(3))
    >>> out, track, added = with_missed_instants(p, np.array([0, 1, 0]))
    >>> out.instant.tolist(), track.tolist(), added.tolist(), bool(np.isnan(out.X[added]).all())
    ([0, 0, 1, 2], [0, 1, 0, 0], [False, False, True, False], True)
    """
    track = np.asarray(track)
    if not len(persons):
        return persons, track, np.zeros(0, dtype=bool)
    index = track_rows(persons.instant, track)
    missed = [(persons.instant[rows[0]] + np.flatnonzero(rows < 0), track[rows[0]])     # rows[0]: its first
              for rows in index if (rows < 0).any()]
    if not missed:
        return persons, track, np.zeros(len(persons), dtype=bool)
    instant = np.concatenate([t for t, _ in missed])
    new_track = np.concatenate([np.full(len(t), k) for t, k in missed])
    K, (V, J) = len(instant), persons.inliers.shape[1:]
    empty = InstantPersons(np.full((K, J, 3), np.nan), instant, np.zeros((K, J)), np.full((K, V), -1),
                           np.zeros((K, V, J), bool), np.zeros((K, V, J), bool), np.full((K, V, J), np.nan),
                           np.full(K, np.nan))
    order = np.argsort(np.concatenate([persons.instant, instant]), kind="stable")
    both = InstantPersons.concatenate([persons, empty], V).take(order)
    added = np.concatenate([np.zeros(len(persons), dtype=bool), np.ones(K, dtype=bool)])[order]
    return both, np.concatenate([track, new_track])[order], added
