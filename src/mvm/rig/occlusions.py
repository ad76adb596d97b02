"""Limb joints through the occlusions of a track: the track's own motion, its bone lengths,
the pose prior and the rays of the views that still see the joint
(:func:`mvm.core.gap_fit.fit_gaps`), with a confidence that falls as the fill's uncertainty
grows (towards the middle of a gap, with its length, away from the views that see it).

A limb joint whose views dispute it (:func:`disputed`: the triangulation refused at least
:data:`DISPUTED_VIEWS` of its keypoints, as where a hidden hand is reported at other things in
most views), or whose bone does (:func:`bone_disputed`: off its track's length for a stretch, as
where the views that do not see a hand all report one other thing), is refused
(:func:`refused_limb_joints`), with the instants between two such of a track and the edges of a
stretch of them (:func:`close_disputes`), and out to where the joint stepped off and back
(:func:`widen_to_steps`). The rig's driver leaves the refused joints out of the smoothing, and
completes those the fill cannot fill as other missing joints. A refused joint is filled as a
missing one from the rays of its views, those that agreed on it left out where no two views
dispute it (:func:`agreed_on_refused`): through such a run a ray is used only where it agrees
with the track's prediction, and a view only if its rays agree where the gap begins and ends (a
detector that reports another thing in a view does it through the stretch, and its rays jump
off the joint's path there).

A joint is filled over a run of missing instants when its parent joint (the shoulder of an
elbow, the elbow of a wrist, the hip of a knee, the knee of an ankle) is known over the whole
run and both are seen on at least one side of it (a run at a track's end is continued from the
side it has); elbows and knees first, so a wrist hidden with its elbow is filled from the
filled elbow. Long runs and those at a track's end are flagged ``inferred``, brief ones
``interpolated``. Pure numpy; no I/O.
"""
from __future__ import annotations

import numpy as np

from mvm.core.completion import INFERRED, INTERPOLATED, complete_tracks, take_rows, track_rows
from mvm.core.gap_fit import fit_gaps
from mvm.core.keypoints import INDEX
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
#: Standard deviation of a joint's distance to the ray of a view's keypoint of it: the
#: detector's noise at a rig's distances. [m]
RAY_SIGMA_M = 0.02
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
#: A limb joint is disputed where the triangulation refused this many of its views' keypoints. [1]
DISPUTED_VIEWS = 2
#: A limb joint is disputed where its bone to its parent is this far from the track's median
#: length, relative to it: most views agreeing on another thing (a hand hidden from all views but
#: one, reported at the other hand in the rest) put it off the bone's sphere. On the simulated rig
#: the bones of seen joints stay within 5 % of their median; such stretches are 10 to 45 % off. [1]
BONE_DISPUTE = 0.15
#: A run of instants where one view's keypoint of an elbow or a wrist is refused, none of them
#: disputed otherwise, is refused whole where the joint's offset from its parent jumps this far
#: (its second difference) where the run begins or ends: the other views took the joint to
#: another thing there. [m]
JUMP_M = 0.12
#: Instants either side within which two refused joints close the stretch between them. [1]
DISPUTE_SPAN = 3
#: A view's run of refused keypoints of a joint goes on over a break of up to this many
#: instants (where its keypoint is missing, or happens to agree with the other views', as where
#: the thing they report lies along its line of sight): the one view that sees a hand is refused
#: all along the stretch where the others report another thing, but not at every instant. [1]
VIEW_BREAK = 2
#: Instants either side of a refused joint refused with it: the edges of a disputed stretch,
#: where the wrong views may still agree, and which the smoothing would carry outwards. [1]
DISPUTE_GROW = 1
#: Refused instants in a row that make a stretch (isolated refusals, a swap's or an outlier's,
#: are not grown). [1]
DISPUTE_STRETCH = 3
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


def disputed(view_refused: np.ndarray) -> np.ndarray:
    """``(Q, 17)`` the limb joints (:data:`LIMB_JOINTS`) of ``Q`` persons whose views dispute
    them: at least :data:`DISPUTED_VIEWS` of their keypoints refused by the triangulation,
    ``view_refused: (Q, V, 17)`` (valid, not among its inliers; reconstructed or not)."""
    out = np.zeros(view_refused.shape[::2], bool)
    refused = view_refused.sum(1)                                                  # (Q, 17)
    out[:, LIMB_JOINTS] = refused[:, LIMB_JOINTS] >= DISPUTED_VIEWS
    return out


def bone_disputed(X: np.ndarray, instant: np.ndarray, track: np.ndarray) -> np.ndarray:
    """``(Q, 17)`` the limb joints of ``X: (Q, 17, 3)`` (NaN: missing) whose bone to their parent
    is off their track's median length by more than :data:`BONE_DISPUTE` of it for
    :data:`DISPUTE_STRETCH` instants or more in a row (a bone off at a lone instant is noise the
    smoothing takes). ``instant, track: (Q,)``.

    >>> X = np.zeros((10, 17, 3)); X[:, 7] = [0.0, 0.3, 0.0]            # the left elbow...
    >>> X[:, 9] = [0.25, 0.3, 0.0]; X[1, 9, 0] = X[5:8, 9, 0] = 0.55    # ...and a wrist off twice
    >>> bone_disputed(X, np.arange(10), np.zeros(10, int))[:, 9].astype(int).tolist()
    [0, 0, 0, 0, 0, 1, 1, 1, 0, 0]
    """
    out = np.zeros(X.shape[:2], bool)
    joints = np.array(LIMB_JOINTS)
    length = np.linalg.norm(X[:, joints] - X[:, LIMB_PARENTS], axis=-1)            # (Q, K), NaN: unknown
    for index in track_rows(np.asarray(instant), np.asarray(track)):
        rows = index[index >= 0]
        known = np.isfinite(length[rows])
        if not known.any():
            continue
        median = np.nanmedian(np.where(known.any(0), length[rows], 0.0), 0)       # (K,)
        with np.errstate(invalid="ignore"):
            off = np.zeros((len(index), len(joints)), bool)
            off[index >= 0] = known & (np.abs(length[rows] - median) > BONE_DISPUTE * median)
        out[rows[:, None], joints] = _stretches(off)[index >= 0]
    return out


def jump_disputed(X: np.ndarray, view_refused: np.ndarray, disputes: np.ndarray, instant: np.ndarray,
                  track: np.ndarray, unit: float = 1.0) -> np.ndarray:
    """``(Q, 17)`` the elbows and wrists of ``X: (Q, 17, 3)`` over the runs of
    :data:`DISPUTE_STRETCH` or more instants where one view's keypoint of them is refused
    (``view_refused: (Q, V, 17)``; short breaks bridged, :data:`VIEW_BREAK`), none of them among
    ``disputes: (Q, 17)``, and their offset from the parent jumps by :data:`JUMP_M` or more (its
    second difference) within :data:`DISPUTE_SPAN` instants of where the run begins or ends: the
    views that do not see a hand took it to another thing as the run began or ended, and
    outvoted the one that sees it (which may agree with them for an instant or two first).
    ``instant, track: (Q,)``; ``unit``: world units per metre."""
    out = np.zeros(X.shape[:2], bool)
    for index in track_rows(np.asarray(instant), np.asarray(track)):
        S, settled = take_rows(X, index), take_rows(disputes, index, False)          # (L, 17, 3), (L, 17)
        views = _bridged(take_rows(view_refused[..., ARM_JOINTS], index, False))    # (L, V, 4)
        for k, j in enumerate(ARM_JOINTS):
            jump = _jumps(_offset(S, j), unit)
            for v in range(views.shape[1]):
                for a, b in zip(*_refused_runs(views[:, v, k], index)):
                    edges = jump[max(a - DISPUTE_SPAN, 0):a + 1].any() or jump[b - 1:b + DISPUTE_SPAN].any()
                    if b - a >= DISPUTE_STRETCH and edges and not settled[a:b, j].any():
                        out[index[a:b], j] = True
    return out


def _offset(S: np.ndarray, joint: int) -> np.ndarray:
    """``(L, 3)`` the offset of a limb ``joint`` from its parent along a track ``S: (L, 17, 3)``."""
    return S[:, joint] - S[:, LIMB_PARENTS[LIMB_JOINTS.index(joint)]]


def _jumps(offset: np.ndarray, unit: float) -> np.ndarray:
    """``(L,)`` the instants where a joint's ``offset: (L, 3)`` from its parent (NaN: unknown)
    jumps: its second difference there (the middle instant) is :data:`JUMP_M` or more (``unit``:
    world units per metre)."""
    jump = np.zeros(len(offset), bool)
    jump[1:-1] = np.nan_to_num(np.linalg.norm(offset[2:] - 2 * offset[1:-1] + offset[:-2], axis=-1)) >= JUMP_M * unit
    return jump


def _steps(jump: np.ndarray, known: np.ndarray) -> np.ndarray:
    """The instants ``t`` of a track where a joint's offset from its parent steps between
    ``t - 1`` and ``t``: ``jump: (L,)`` (:func:`_jumps`) at both, or at one where the other is
    next to where the offset is not known (``known: (L,)``), and no second difference there.

    >>> jump = np.zeros(12, bool); jump[[3, 4, 8]] = True; known = np.arange(12) != 10
    >>> _steps(jump, known).tolist()                  # between 3 and 4; between 8 and 9 (10 unknown)
    [4, 9]
    """
    edge = known & ~(np.r_[False, known[:-1]] & np.r_[known[1:], False])            # no second difference there
    at = jump | edge
    return np.flatnonzero(at[:-1] & at[1:] & (jump[:-1] | jump[1:])) + 1


def widen_to_steps(refused: np.ndarray, X: np.ndarray, instant: np.ndarray, track: np.ndarray, unit: float = 1.0,
                   joints=ARM_JOINTS) -> np.ndarray:
    """``refused: (Q, 17)`` (:func:`extend_disputes`) widened, along each track, for ``joints``,
    over the pieces of the joint's known series in ``X: (Q, 17, 3)`` between two steps of its
    offset from its parent (two jumps in a row, :func:`_jumps`, at ``t - 1`` and ``t``: a step
    between them), or between one and where the joint is not known (the instant next to it
    refused), of which at least half are refused: the views
    that do not see a hand take it to the other thing they agree on at once, and leave it at once
    (or lose it), but the one view that sees it is refused only where it has a keypoint (it may
    be missing as the stretch begins or ends, or agree for an instant). ``instant, track:
    (Q,)``; ``unit``: world units per metre.

    On the simulated rig of ``benchmarks/rig_occlusion.py``, a wrist seen at its place by one
    view of five while the four others agree on a point 20-40 cm off was left as triangulated at
    a few of the stretches' first or last instants, 240-260 mm off, and the fill through the
    stretch started from there: 33-46 mm off without this, 20-24 mm with it (the oracle given the
    true ends and the one view: 10-30 mm)."""
    refused = np.asarray(refused, bool)
    out = refused.copy()
    for index in track_rows(np.asarray(instant), np.asarray(track)):
        S, R = take_rows(X, index), take_rows(refused, index, False)              # (L, 17, 3), (L, 17)
        for j in joints:
            offset = _offset(S, j)
            known = np.isfinite(offset).all(-1)
            steps = _steps(_jumps(offset, unit), known)
            is_step = np.zeros(len(S) + 1, bool)
            is_step[steps] = True
            for first, stop in zip(*runs(known)):
                cuts = np.r_[first, steps[(steps > first) & (steps < stop)], stop]
                for a, b in zip(cuts[:-1], cuts[1:]):
                    ends = (is_step[a] or R[a, j]) and (is_step[b] or R[b - 1, j]) and (is_step[a] or is_step[b])
                    if ends and 2 * R[a:b, j].sum() >= b - a:
                        while a - 1 > first and is_step[a - 1]:                    # into steps in a row
                            a -= 1
                        while b + 1 < stop and is_step[b + 1]:
                            b += 1
                        out[index[a:b], j] = True
    return out


def _window_count(mask: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """``(L, K)`` how many of ``mask: (L, K)`` are true from ``t + lo`` to ``t + hi`` (clipped)."""
    L = len(mask)
    c = np.concatenate([np.zeros((1,) + mask.shape[1:], int), np.cumsum(mask, 0)])    # (L + 1, K)
    t = np.arange(L)
    return c[np.clip(t + hi + 1, 0, L)] - c[np.clip(t + lo, 0, L)]


def _bridged(mask: np.ndarray, k: int = VIEW_BREAK) -> np.ndarray:
    """``(L, ...)``: ``mask: (L, ...)`` with its breaks along the first axis of up to ``k`` false
    instants between two runs of two or more true ones made true (a lone true one is not joined:
    one stray keypoint is not a stretch).

    >>> _bridged(np.array([1, 1, 0, 0, 1, 1, 0, 0, 0, 1, 1, 0, 1], bool)).astype(int).tolist()
    [1, 1, 1, 1, 1, 1, 0, 0, 0, 1, 1, 0, 1]
    """
    core = _stretches(mask, 2)
    t = np.arange(len(mask)).reshape((-1,) + (1,) * (mask.ndim - 1))
    before = np.maximum.accumulate(np.where(core, t, -1), axis=0)                    # the last core instant so far
    after = np.flip(np.minimum.accumulate(np.flip(np.where(core, t, len(mask)), 0), axis=0), 0)   # the next one
    return mask | ((before >= 0) & (after < len(mask)) & (after - before - 1 <= k))


def _refused_runs(refused: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The runs (:func:`~mvm.rig.tracking.runs`) of one view's refused keypoints of a joint along
    a track, ``refused: (L,)`` at its rows ``index: (L,)`` (bridged: :func:`_bridged`), never
    over an instant the track was not seen."""
    return runs((index >= 0) & refused)


def _stretches(mask: np.ndarray, m: int = DISPUTE_STRETCH) -> np.ndarray:
    """``(L, K)``: the instants of ``mask: (L, K)`` in runs of ``m`` or more true ones in a row."""
    return _window_count(_window_count(mask, 0, m - 1) == m, 1 - m, 0) > 0


def close_disputes(refused: np.ndarray, instant: np.ndarray, track: np.ndarray, span: int = DISPUTE_SPAN,
                   grow: int = DISPUTE_GROW) -> np.ndarray:
    """``refused: (Q, 17)`` (:func:`disputed`) with the joints of a track between two refused
    ones at most ``span`` instants away on either side refused too, and, around a stretch of
    :data:`DISPUTE_STRETCH` or more so closed, ``grow`` instants either side: within and at the
    edges of a stretch where a hidden hand is reported at other things, the instants where
    wrong views happen to agree are as wrong. ``instant, track: (Q,)``."""
    refused = np.asarray(refused, bool)
    out = refused.copy()
    for index in track_rows(np.asarray(instant), np.asarray(track)):
        D = take_rows(refused, index, False)                                       # (L, 17)
        closed = (_window_count(D, -span, 0) > 0) & (_window_count(D, 0, span) > 0)
        closed |= _window_count(_stretches(closed), -grow, grow) > 0
        present = index >= 0
        out[index[present]] |= closed[present]
    return out


def extend_disputes(refused: np.ndarray, view_refused: np.ndarray, instant: np.ndarray, track: np.ndarray,
                    joints=ARM_JOINTS) -> np.ndarray:
    """``refused: (Q, 17)`` (:func:`close_disputes`) extended, along each track, for ``joints``,
    over the runs of consecutive instants where one view's keypoint of the joint is refused by
    the triangulation (``view_refused: (Q, V, 17)``; breaks of up to :data:`VIEW_BREAK`
    instants bridged) that touch a refused instant: where most
    views agree on another thing, the one view that sees the joint is refused all along the
    stretch, but the bone betrays the other thing only where it lies off the bone's sphere.
    ``instant, track: (Q,)``."""
    refused = np.asarray(refused, bool)
    out = refused.copy()
    for index in track_rows(np.asarray(instant), np.asarray(track)):
        R = take_rows(refused, index, False)                                       # (L, 17)
        views = _bridged(take_rows(view_refused[..., joints], index, False))       # (L, V, K)
        for k, j in enumerate(joints):
            for v in range(views.shape[1]):
                for a, b in zip(*_refused_runs(views[:, v, k], index)):
                    if R[a:b, j].any():
                        out[index[a:b], j] = True
    return out


def with_refused_elbows(refused: np.ndarray, inliers: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``refused: (Q, 17)`` (the disputes, before they are closed into stretches) with the wrists
    triangulated from none but the views that agreed on their refused elbow
    (:func:`agreed_on_refused`; ``inliers``, ``valid``: ``(Q, V, 17)``): those views took the arm
    to another thing, the other arm, whose forearm is as long."""
    out = np.array(refused, bool)
    agreed = agreed_on_refused(out, inliers, valid)                                 # (Q, V, 17)
    for joint, parent in LIMB_PASSES[1]:
        if joint in ARM_JOINTS:
            made, suspect = inliers[:, :, joint], agreed[:, :, parent]
            out[:, joint] |= made.any(1) & suspect.any(1) & ~(made & ~suspect).any(1)
    return out


def refused_limb_joints(X: np.ndarray, inliers: np.ndarray, valid: np.ndarray, instant: np.ndarray,
                        track: np.ndarray, unit: float = 1.0) -> np.ndarray:
    """``(Q, 17)`` the limb joints of tracked persons ``X: (Q, 17, 3)`` refused, to be filled
    (:func:`fill_occlusions`): those their views dispute (:func:`disputed`, of the
    triangulation's ``inliers`` among the ``valid: (Q, V, 17)`` keypoints) or their bone does
    (:func:`bone_disputed`), an elbow's or a wrist's run of one view refused where it jumps at the
    run's ends (:func:`jump_disputed`; ``unit``: world units per metre), closed into stretches
    (:func:`close_disputes`) and, for the elbows
    and wrists, extended over the runs of one view refused next to them (:func:`extend_disputes`;
    on the real 4-camera capture of ``benchmarks/real_footage.py`` extending the legs too made a
    hip-knee bone's length vary more, its standard deviation 18 -> 25 mm, where a leg crossing
    the other keeps one view refused) and widened to the steps of their offset around them
    (:func:`widen_to_steps`). ``instant, track: (Q,)``."""
    view_refused = valid & ~inliers
    disputes = disputed(view_refused) | bone_disputed(X, instant, track)
    disputes = with_refused_elbows(disputes | jump_disputed(X, view_refused, disputes, instant, track, unit), inliers,
                                   valid)
    refused = close_disputes(disputes, instant, track)
    return widen_to_steps(extend_disputes(refused, view_refused, instant, track), X, instant, track, unit)


def agreed_on_refused(refused: np.ndarray, inliers: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``(Q, V, 17)`` the keypoints that made the ``refused: (Q, 17)`` joints their views do not
    dispute (:func:`disputed`; ``inliers``, ``valid``: ``(Q, V, 17)`` as there): the views agreed
    on the point, and its bone or its jump refused it, so they agreed on another thing (the
    other hand, a prop) and are left out of the fill. Where two views dispute a refused joint,
    its inliers may be the views that see it, and they are kept.

    On the simulated rig of ``benchmarks/rig_occlusion.py``, a wrist seen at its place by one
    view of five while the four others agree on a point 20-40 cm off was 48-63 mm from the
    truth with their rays, and is 33-46 mm without them (the oracle given the true ends and the
    one view: 10-30 mm)."""
    agreed = np.asarray(refused, bool) & ~disputed(valid & ~inliers)
    return agreed[:, None, :] & inliers


def refused_parents(refused: np.ndarray) -> np.ndarray:
    """``(Q, 17)`` the elbows and knees of the wrists and ankles ``refused: (Q, 17)``, and the
    shoulders of the refused elbows, where not refused themselves: the refinement's bone term
    pulled them towards the refused joint.

    On the simulated rig of ``benchmarks/rig_occlusion.py``, where most views agree on an elbow
    and a wrist that are not there, the shoulders were 20-32 mm off (6.6-7.2 mm where the arm is
    only missing), and are 6-8 mm off with theirs given. The hips of refused knees are not given:
    on the real 4-camera capture of ``benchmarks/real_footage.py`` (calibration from the people),
    refining a hip again without its refused knee made the thigh's length vary more, its
    standard deviation 18 -> 23 mm."""
    refused = np.asarray(refused, bool)
    out = np.zeros_like(refused)
    for joint, parent in LIMB_PASSES[1] + tuple(pair for pair in LIMB_PASSES[0] if pair[0] in ARM_JOINTS):
        out[:, parent] |= refused[:, joint]
    return out & ~refused


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
            if not (b - a <= max_gap and (at_start or at_end) and seen[a:b, p].all()):
                continue
            before = [index[a - 2] if a >= 2 and both[a - 2] else -1, index[a - 1] if at_start else -1]
            after = [index[b] if at_end else -1, index[b + 1] if b + 1 < len(S) and both[b + 1] else -1]
            flag = INTERPOLATED if at_start and at_end and b - a < long_gap else INFERRED
            gate = RAY_GATE_SIGMAS if disputes[a:b, j].any() else np.inf
            gaps.append((index[a:b], before, after, j, p, length, sigma, flag, gate))
    return gaps


def _fill_group(X: np.ndarray, group: list[tuple], origin: np.ndarray, direction: np.ndarray,
                prior_X: np.ndarray | None, unit: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fit ``group``'s gaps (of one length, :func:`_track_gaps`): ``(rows (N, n), joints (N,),
    joint positions (N, n, 3), posterior deviations (N, n))``."""
    rows = np.array([g[0] for g in group])                                         # (N, n)
    j = np.array([g[3] for g in group])
    p = np.array([g[4] for g in group])
    ends = np.array([g[1] + g[2] for g in group])                                  # (N, 4)
    known = X[np.maximum(ends, 0), j[:, None]] - X[np.maximum(ends, 0), p[:, None]]
    known[ends < 0] = np.nan
    parent = X[rows, p[:, None]]                                                   # (N, n, 3)
    prior = None if prior_X is None else prior_X[rows, j[:, None]] - parent
    o = origin[rows, :, j[:, None]] - parent[:, :, None]                           # (N, n, V, 3)
    d = direction[rows, :, j[:, None]]
    bone = np.array([g[5] for g in group])
    r, std, _ = fit_gaps(known[:, :2], known[:, 2:], bone, np.array([g[6] for g in group]), BONE_SIGMA * bone,
                         prior, PRIOR_SIGMA_M * unit, o, d, RAY_SIGMA_M * unit, RAY_GATE_M * unit,
                         np.array([g[8] for g in group]))
    return rows, j, parent + r, std


def fill_occlusions(X: np.ndarray, instant: np.ndarray, track: np.ndarray, origin: np.ndarray,
                    direction: np.ndarray, prior_X: np.ndarray | None = None, long_gap: int = 5,
                    max_gap: int = 90, unit: float = 1.0, refused: np.ndarray | None = None,
                    root_gap: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fill the limb joints of tracked persons through runs of missing instants.

    Args:
        X: ``(Q, 17, 3)`` persons, NaN where a joint is missing; instant, track: ``(Q,)``.
        origin, direction: ``(Q, V, 17, 3)`` the rays of each person's 2D keypoints
            (:func:`rays`), NaN where a view has none.
        prior_X: ``(Q, 17, 3)`` the pose prior's guess of the missing joints (None: no prior).
        long_gap: runs from this long, and those at a track's end, are flagged inferred;
            shorter ones interpolated. [instants]
        max_gap: the longest run filled. [instants]
        unit: world units per metre (the module's constants are in metres).
        refused: ``(Q, 17)`` joints of ``X`` refused as outliers (:func:`disputed`), filled as
            missing ones (those that cannot be are left missing); the rays of a run with one
            are tried against the track's motion first (``gate_sigmas`` of
            :func:`mvm.core.gap_fit.fit_gaps`).
        root_gap: the roots of the limbs (:data:`ROOT_JOINTS`) missing for up to this many
            instants are interpolated first (flagged interpolated, confidence 0, as the
            completion after the fill would leave them), so that the limbs hanging from them
            can be filled through the gap. [instants]
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
    for joints in LIMB_PASSES:
        gaps = [g for index in series for g in _track_gaps(X, index, refused, joints, long_gap, max_gap, unit)]
        for n in sorted({len(g[0]) for g in gaps}):
            group = [g for g in gaps if len(g[0]) == n]
            rows, j, filled, std = _fill_group(X, group, origin, direction, prior_X, unit)
            X[rows, j[:, None]] = filled
            flags[rows, j[:, None]] = np.array([g[7] for g in group])[:, None]
            confidence[rows, j[:, None]] = 1.0 / (1.0 + (std / (CONFIDENCE_SCALE_M * unit)) ** 2)
    return X, flags, confidence
