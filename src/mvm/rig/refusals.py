"""Which limb joints of a rig's tracks are refused as outliers, to be filled through their
occlusions (:func:`mvm.rig.occlusions.fill_occlusions`).

A limb joint whose views dispute it (:func:`disputed`: the triangulation refused at least
:data:`DISPUTED_VIEWS` of its keypoints, as where a hidden hand is reported at other things in
most views), or whose bone does (:func:`bone_disputed`: off its track's length for a stretch, as
where the views that do not see a hand all report one other thing), or whose one view's refused
run begins or ends where it jumps (:func:`jump_disputed`), is refused
(:func:`refused_limb_joints`), with a wrist made only by the views that made its refused elbow
(:func:`with_refused_elbows`), the instants between two such of a track and the edges of
a stretch of them (:func:`close_disputes`), the runs of the one view refused next to them
(:func:`extend_disputes`), and out to where the joint stepped off and back
(:func:`widen_to_steps`). A limb joint off its track for an instant or two and back is refused
too (:func:`spikes`). The views that agreed on a refused joint no two views dispute are left
out of its fill (:func:`agreed_on_refused`), and the parents the refinement's bone term pulled
towards it are refined again (:func:`refused_parents`). Pure numpy; no I/O.
"""
from __future__ import annotations

import numpy as np

from mvm.core.completion import take_rows, track_rows
from mvm.rig.occlusions import ARM_JOINTS, LIMB_JOINTS, LIMB_PARENTS, LIMB_PASSES
from mvm.rig.tracking import runs

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
#: The longest piece of a track where a limb joint off its track and back is refused
#: (:func:`spikes`). [instants]
SPIKE_INSTANTS = 2
#: ... off by this much (its offset from its limb's root, from those at the instants either side). [m]
SPIKE_M = 0.2
#: The joint each limb joint's chain hangs from (the shoulder of an elbow and of a wrist, the hip
#: of a knee and of an ankle), in the order of ``LIMB_JOINTS``.
LIMB_ROOTS = [LIMB_PARENTS[LIMB_JOINTS.index(p)] if p in LIMB_JOINTS else p for p in LIMB_PARENTS]


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


def spikes(X: np.ndarray, instant: np.ndarray, track: np.ndarray, unit: float = 1.0) -> np.ndarray:
    """``(Q, 17)`` the limb joints of ``X: (Q, 17, 3)`` (NaN: unknown) over the pieces of their
    track of at most :data:`SPIKE_INSTANTS` where their offset from their limb's root
    (:data:`LIMB_ROOTS`: a wrist's from the shoulder, not from an elbow that may be the one off)
    is :data:`SPIKE_M` or more from its offsets at the instants either side, which are less than
    that from each other: the joint left its track and came back, as where a view's keypoint
    was another person's and the triangulation kept it. Left in, the smoothing spreads such a
    point over the instants around it, and the fill of a hidden joint starts from it.
    ``instant, track: (Q,)``; ``unit``: world units per metre.

    On the simulated rig of ``benchmarks/rig_occlusion.py``, wrists reported off in all views
    but the one that sees them were filled 20-29 mm off without this, and 17-28 mm with it. On
    the real capture of ``benchmarks/real_footage.py``, the pieces between two steps of the
    offset (:func:`_steps`, as :func:`widen_to_steps` takes them) held a wrist flickering 10 cm
    an instant and the legs where they cross, and refusing those made the jitter worse.

    >>> X = np.zeros((9, 17, 3)); X[:, 7] = [0.0, 0.3, 0.0]; X[:, 9] = [0.25, 0.3, 0.0]
    >>> X[2, 9, 2] = 0.4                               # the left wrist, 40 cm off once...
    >>> X[6:, 9, 2] = 0.3                              # ...and 30 cm off from 6 on (a step, not a spike)
    >>> spikes(X, np.arange(9), np.zeros(9, int))[:, 9].astype(int).tolist()
    [0, 0, 1, 0, 0, 0, 0, 0, 0]
    """
    out = np.zeros(X.shape[:2], bool)
    limit = SPIKE_M * unit
    for index in track_rows(np.asarray(instant), np.asarray(track)):
        S = take_rows(X, index)                                                    # (L, 17, 3)
        offset = S[:, LIMB_JOINTS] - S[:, LIMB_ROOTS]                              # (L, K, 3), NaN: unknown
        L = len(S)
        off = np.zeros(offset.shape[:2], bool)
        with np.errstate(invalid="ignore"):
            for k in range(1, min(SPIKE_INSTANTS, L - 2) + 1):                     # pieces t + 1 .. t + k
                before, after = offset[:L - k - 1], offset[k + 1:]                 # (L - k - 1, K, 3)
                spike = np.linalg.norm(after - before, axis=-1) < limit
                for i in range(1, k + 1):
                    piece = offset[i:L - k - 1 + i]
                    spike &= np.minimum(np.linalg.norm(piece - before, axis=-1),
                                        np.linalg.norm(piece - after, axis=-1)) >= limit
                for i in range(1, k + 1):
                    off[i:L - k - 1 + i] |= spike
        present = index >= 0
        out[np.ix_(index[present], LIMB_JOINTS)] = off[present]
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


def with_refused_elbows(refused: np.ndarray, inliers: np.ndarray) -> np.ndarray:
    """``refused: (Q, 17)`` with the wrists triangulated from none but the views that made their
    refused elbow (its ``inliers: (Q, V, 17)``, the triangulation's): those views took the arm to
    another thing, the other arm, whose forearm is as long, so that nothing betrays the wrist.
    :func:`refused_limb_joints` applies it to the disputes, and again to the refusals once grown,
    widened and extended: where an elbow's refusal reaches the instants at a stretch's edges,
    where the views switch to the other arm and agree on it."""
    out = np.array(refused, bool)
    for joint, parent in LIMB_PASSES[1]:
        if joint in ARM_JOINTS:
            made, suspect = inliers[:, :, joint], inliers[:, :, parent] & out[:, None, parent]
            out[:, joint] |= made.any(1) & suspect.any(1) & ~(made & ~suspect).any(1)
    return out


def refused_limb_joints(X: np.ndarray, inliers: np.ndarray, valid: np.ndarray, instant: np.ndarray,
                        track: np.ndarray, unit: float = 1.0) -> np.ndarray:
    """``(Q, 17)`` the limb joints of tracked persons ``X: (Q, 17, 3)`` refused, to be filled
    (:func:`mvm.rig.occlusions.fill_occlusions`): those their views dispute (:func:`disputed`, of the
    triangulation's ``inliers`` among the ``valid: (Q, V, 17)`` keypoints) or their bone does
    (:func:`bone_disputed`), an elbow's or a wrist's run of one view refused where it jumps at the
    run's ends (:func:`jump_disputed`; ``unit``: world units per metre), closed into stretches
    (:func:`close_disputes`) and, for the elbows
    and wrists, extended over the runs of one view refused next to them (:func:`extend_disputes`;
    on the real 4-camera capture of ``benchmarks/real_footage.py`` extending the legs too made a
    hip-knee bone's length vary more, its standard deviation 18 -> 25 mm, where a leg crossing
    the other keeps one view refused) and widened to the steps of their offset around them
    (:func:`widen_to_steps`); with the limb joints off their track for an instant or two and back
    (:func:`spikes`) and the wrists of the elbows so refused (:func:`with_refused_elbows` again:
    on the simulated rig of ``benchmarks/rig_occlusion.py``, the other arm's wrist was kept where
    its stretch began, 272 mm off, and the fill went on from it); and all of them closed once
    more (no growing): an instant left between two refusals of these later kinds is as suspect
    (there, an elbow that most views took to another thing, kept at one instant of a 40-instant
    stretch, held the fills either side of it up to 310 mm off). ``instant, track: (Q,)``."""
    view_refused = valid & ~inliers
    disputes = disputed(view_refused) | bone_disputed(X, instant, track)
    disputes = with_refused_elbows(disputes | jump_disputed(X, view_refused, disputes, instant, track, unit), inliers)
    refused = close_disputes(disputes, instant, track)
    refused = widen_to_steps(extend_disputes(refused, view_refused, instant, track), X, instant, track, unit)
    refused = with_refused_elbows(refused | spikes(X, instant, track, unit), inliers)
    return close_disputes(refused, instant, track, grow=0)


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
