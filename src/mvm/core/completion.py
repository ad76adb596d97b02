"""Completion of people: every joint of a person reconstructed, observed or not, and flagged.

Two sources, used in this order:

- **time** (:func:`interpolate_series`): a joint missing at some instants of a track is
  interpolated (cubic Hermite, tangents from the neighbouring observations) between the track's
  neighbouring instants where it was observed, over gaps of at most ``max_gap`` instants (never
  extrapolated past a track's ends);
- **the body** (:func:`infer_missing`): a joint still missing is the conditional expectation of
  the GMM pose prior (:mod:`mvm.core.prior`) given the person's present joints, computed in the
  person's own canonical frame (pelvis origin, torso-length scale) and mapped back to the world.
  A person lacking the joints that define that frame (a hip or a shoulder) is first given them
  from the prior's component means aligned (similarity transform) to the present joints.

Every joint carries a flag: :data:`OBSERVED`, :data:`INTERPOLATED`, :data:`INFERRED`, or
:data:`MISSING` (too little of the person to complete). Arrays in, arrays out; no I/O.
"""
from __future__ import annotations

import numpy as np

from mvm.core.geometry import similarity_transform
from mvm.core.keypoints import NUM_JOINTS
from mvm.core.prior import body_frame

MISSING, OBSERVED, INTERPOLATED, INFERRED = 0, 1, 2, 3
#: The names of the flags, as written in ``poses3d.json`` / ``.jsonl`` (index = flag value).
FLAG_NAMES = ("missing", "observed", "interpolated", "inferred")


def flag_names(flags: np.ndarray) -> list:
    """``flags: (..., 17)`` integers -> nested lists of names (as written in the JSON files).

    >>> flag_names(np.array([[OBSERVED, INTERPOLATED], [INFERRED, MISSING]]))
    [['observed', 'interpolated'], ['inferred', 'missing']]
    """
    return np.asarray(FLAG_NAMES, dtype=object)[np.asarray(flags, dtype=int)].tolist()


def parse_flags(names, field: str = "flags") -> np.ndarray:
    """Flag names -> integers; an unknown name raises ``ValueError`` naming it and the known ones.

    >>> parse_flags(["observed", "inferred"])
    array([1, 3], dtype=int8)
    >>> parse_flags(["guessed"])
    Traceback (most recent call last):
    ...
    ValueError: flags: unknown flag 'guessed' (known: missing, observed, interpolated, inferred)
    """
    lookup = {n: i for i, n in enumerate(FLAG_NAMES)}
    try:
        return np.array([lookup[n] for n in names], dtype=np.int8)
    except (KeyError, TypeError):
        bad = next((n for n in names if n not in lookup), names)
        raise ValueError(f"{field}: unknown flag {bad!r} (known: {', '.join(FLAG_NAMES)})") from None


def interpolate_series(series: np.ndarray, max_gap: int) -> tuple[np.ndarray, np.ndarray]:
    """Interpolation of one track along time: a cubic Hermite curve between the observations
    on either side of a gap, with tangents from their neighbouring observations (the secant where
    there are none), so a swinging limb follows its curve rather than the chord.

    Args:
        series: ``(L, J, 3)`` consecutive instants of one track, NaN where a joint (or the whole
            person) is missing.
        max_gap: the longest run of missing instants that is filled, in instants (0: none).
    Returns:
        ``(filled: (L, J, 3), interpolated: (L, J) bool)``. Only gaps with an observation on both
        sides are filled; the ends of a track are never extrapolated.

    A joint moving at constant velocity, missing at instants 1 and 2, is filled on its line:

    >>> series = np.arange(5.0)[:, None, None] * np.ones((5, 1, 3))
    >>> series[1:3] = np.nan
    >>> filled, interpolated = interpolate_series(series, max_gap=2)
    >>> filled[:, 0, 0], interpolated[:, 0]
    (array([0., 1., 2., 3., 4.]), array([False,  True,  True, False, False]))
    >>> bool(np.isnan(interpolate_series(series, max_gap=1)[0][1:3]).all())     # a gap too long
    True
    """
    series = np.asarray(series, dtype=float)
    if series.ndim != 3 or series.shape[2] != 3:
        raise ValueError(f"series: expected (L, J, 3), got {series.shape}")
    if max_gap < 0:
        raise ValueError(f"max_gap: must be >= 0, got {max_gap}")
    L = len(series)
    observed = np.isfinite(series).all(-1)                                        # (L, J)
    index = np.arange(L)[:, None]
    prev = np.maximum.accumulate(np.where(observed, index, -1), axis=0)             # (L, J)
    nxt = np.minimum.accumulate(np.where(observed, index, L)[::-1], axis=0)[::-1]
    fill = ~observed & (prev >= 0) & (nxt < L) & (nxt - prev - 1 <= max_gap)
    out = series.copy()
    if fill.any():
        t, j = np.nonzero(fill)
        p, n = prev[t, j], nxt[t, j]
        a, b = series[p, j], series[n, j]                                           # (F, 3)
        secant = (b - a) / (n - p)[:, None]                                          # per instant
        # Tangents from the neighbouring observations where there are some, else the secant.
        before = (p >= 1) & observed[np.maximum(p - 1, 0), j]
        after = (n + 1 < L) & observed[np.minimum(n + 1, L - 1), j]
        da = np.where(before[:, None], a - series[np.maximum(p - 1, 0), j], secant)
        db = np.where(after[:, None], series[np.minimum(n + 1, L - 1), j] - b, secant)
        h = (n - p).astype(float)
        s = ((t - p) / h)[:, None]
        # Cubic Hermite between the two observations (tangents in units of the gap).
        out[t, j] = ((2 * s ** 3 - 3 * s ** 2 + 1) * a + (s ** 3 - 2 * s ** 2 + s) * h[:, None] * da
                     + (-2 * s ** 3 + 3 * s ** 2) * b + (s ** 3 - s ** 2) * h[:, None] * db)
    return out, fill


def _frame_from_means(pose: np.ndarray, means: np.ndarray) -> np.ndarray:
    """``pose: (17, 3)`` with NaN, ``means: (L, 17, 3)`` canonical -> the pose with its missing
    joints taken from the component mean that aligns best to its present joints."""
    present = np.isfinite(pose).all(-1)
    s, R, t = similarity_transform(means[:, present], np.broadcast_to(pose[present], means[:, present].shape))
    placed = s[:, None, None] * np.einsum("lij,lkj->lki", R, means) + t[:, None]   # (L, 17, 3)
    residual = np.linalg.norm(placed[:, present] - pose[present], axis=-1).mean(1)
    best = placed[int(np.argmin(residual))]
    return np.where(present[:, None], pose, best)


def conditional_mean(prior, canonical: np.ndarray) -> np.ndarray:
    """``E[x_missing | x_present]`` under the GMM prior. ``canonical: (P, 17, 3)`` with NaN for
    missing joints -> ``(P, 17, 3)`` with the missing joints filled (present ones unchanged).

    Per component ``l``: ``μ_m + Σ_mo Σ_oo⁻¹ (x_o − μ_o)``; the components are weighted by their
    posterior given the present joints (the marginal likelihoods of :meth:`PosePrior.log_weighted_densities`).
    Persons without any present joint are returned unchanged.
    """
    canonical = np.asarray(canonical, dtype=float)
    present = np.isfinite(canonical).all(-1)                                      # (P, 17)
    out = canonical.copy()
    todo = present.any(1) & ~present.all(1)
    if not todo.any():
        return out
    rows_all = np.flatnonzero(todo)
    responsibility = prior.responsibilities(np.where(present[rows_all, :, None], canonical[rows_all], np.nan))
    patterns, inverse = np.unique(present[rows_all], axis=0, return_inverse=True)
    flat = canonical.reshape(len(canonical), 3 * NUM_JOINTS)
    for k, pattern in enumerate(patterns):
        sel = np.flatnonzero(inverse.reshape(-1) == k)
        rows = rows_all[sel]
        o = np.repeat(pattern, 3)
        m = ~o
        x_o = flat[np.ix_(rows, o)]                                                # (n, K)
        cov = prior.covariances[:, o]
        gain = np.linalg.solve(cov[:, :, o], cov[:, :, m])                          # (L, K, M): Σ_oo⁻¹ Σ_om
        means = prior.means[:, m][:, None] + np.matmul(x_o[None] - prior.means[:, None, o], gain)  # (L, n, M)
        estimate = np.einsum("nl,lnm->nm", responsibility[sel], means)
        filled = flat[rows].copy()
        filled[:, m] = estimate
        out[rows] = filled.reshape(len(rows), NUM_JOINTS, 3)
    return out


def infer_missing(X: np.ndarray, prior, min_joints: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Joints a person lacks, inferred from the rest of its body with the pose prior.

    Args:
        X: ``(P, 17, 3)`` world joints, NaN where missing.
        prior: a :class:`mvm.core.prior.PosePrior`.
        min_joints: persons with fewer present joints are left as they are.
    Returns:
        ``(X_completed: (P, 17, 3), inferred: (P, 17) bool)``.
    """
    X = np.asarray(X, dtype=float)
    if X.ndim != 3 or X.shape[1:] != (NUM_JOINTS, 3):
        raise ValueError(f"X: expected (P, 17, 3), got {X.shape}")
    present = np.isfinite(X).all(-1)
    todo = ~present.all(1) & (present.sum(1) >= max(min_joints, 3))
    out = X.copy()
    inferred = np.zeros(present.shape, dtype=bool)
    if not todo.any():
        return out, inferred
    rows = np.flatnonzero(todo)
    posed = X[rows]
    rotation, centre, scale = body_frame(posed)
    no_frame = ~np.isfinite(scale)
    if no_frame.any():
        means = prior.means.reshape(-1, NUM_JOINTS, 3)
        seeded = np.array([_frame_from_means(posed[i], means) for i in np.flatnonzero(no_frame)])
        r2, c2, s2 = body_frame(seeded)
        rotation[no_frame], centre[no_frame], scale[no_frame] = r2, c2, s2
    ok = np.isfinite(scale)
    rows, rotation, centre, scale, posed = rows[ok], rotation[ok], centre[ok], scale[ok], posed[ok]
    canonical = np.einsum("pij,pkj->pki", rotation, posed - centre[:, None]) / scale[:, None, None]
    completed = conditional_mean(prior, canonical)
    world = np.einsum("pji,pkj->pki", rotation, completed * scale[:, None, None]) + centre[:, None]
    missing = ~present[rows]
    out[rows] = np.where(missing[..., None], world, posed)
    inferred[rows] = missing & np.isfinite(world).all(-1)
    out[~np.isfinite(out).all(-1)] = np.nan
    return out, inferred


def complete_persons(X: np.ndarray, prior=None, min_joints: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Complete the persons of one scene (no time: the prior only). ``X: (P, 17, 3)`` ->
    ``(X: (P, 17, 3), flags: (P, 17) int8)``; without a prior only the flags are computed."""
    X = np.asarray(X, dtype=float)
    flags = np.where(np.isfinite(X).all(-1), OBSERVED, MISSING).astype(np.int8)
    if prior is None:
        return X.copy(), flags
    out, inferred = infer_missing(X, prior, min_joints)
    flags[inferred] = INFERRED
    return out, flags


def track_rows(instant: np.ndarray, track: np.ndarray) -> list[np.ndarray]:
    """Each track's rows by instant, tracks in the order of their ids: ``(L,)`` from its first
    instant to its last, -1 where it was not seen. ``instant, track: (Q,)``.

    >>> [r.tolist() for r in track_rows(np.array([0, 2, 0, 1]), np.array([5, 5, 7, 7]))]
    [[0, -1, 1], [2, 3]]
    """
    order = np.lexsort((instant, track))
    out = []
    for rows in np.split(order, np.flatnonzero(np.diff(track[order])) + 1):
        t0 = instant[rows].min()
        index = np.full(instant[rows].max() - t0 + 1, -1)
        index[instant[rows] - t0] = rows
        out.append(index)
    return out


def take_rows(A: np.ndarray, index: np.ndarray, fill=np.nan) -> np.ndarray:
    """``A: (Q, ...)`` at the rows ``index: (L,)`` of one track (:func:`track_rows`), ``fill``
    where it was not seen (-1) -> ``(L, ...)``.

    >>> take_rows(np.array([[1.0], [2.0]]), np.array([1, -1, 0])).ravel().tolist()
    [2.0, nan, 1.0]
    """
    seen = (index >= 0).reshape((-1,) + (1,) * (np.ndim(A) - 1))
    return np.where(seen, A[np.maximum(index, 0)], fill)


def complete_tracks(X: np.ndarray, instant: np.ndarray, track: np.ndarray, max_gap: int,
                    prior=None, min_joints: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Complete the persons of a tracked sequence: time first, then the prior.

    Args:
        X: ``(Q, 17, 3)`` persons, NaN where missing; instant, track: ``(Q,)`` integers.
        max_gap: longest gap filled by interpolation, in instants.
        prior: the pose prior for what time cannot fill (None: time only).
    Returns:
        ``(X: (Q, 17, 3), flags: (Q, 17) int8)``.
    """
    X = np.asarray(X, dtype=float)
    instant = np.asarray(instant)
    track = np.asarray(track)
    out = X.copy()
    flags = np.where(np.isfinite(X).all(-1), OBSERVED, MISSING).astype(np.int8)
    if len(X) and max_gap > 0:
        for index in track_rows(instant, track):
            seen = index >= 0
            filled, interpolated = interpolate_series(take_rows(X, index), max_gap)
            rows = index[seen]
            out[rows] = filled[seen]
            flags[rows] = np.where(interpolated[seen], INTERPOLATED, flags[rows])
    if prior is not None:
        out, inferred = infer_missing(out, prior, min_joints)
        flags[inferred] = INFERRED
    return out, flags
