"""Per-joint triangulation of grouped 2D poses: confidence-weighted DLT inside RANSAC,
vectorized over persons, joints and hypotheses.

A group is padded to ``M`` (its largest size) views; arrays have axes ``(P, M, J)``.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from mvm.core.geometry import dlt_terms, ray_spread_deg, solve_dlt, weighted_dlt
from mvm.core.image_units import medians_by, view_sizes
from mvm.core.scene import Cameras, Poses2D


@dataclass
class GroupObservations:
    """The 2D keypoints of ``P`` groups, padded to ``M`` views.

    Attributes:
        xy: ``(P, M, J, 2)`` pixels; conf: ``(P, M, J)`` (0 where missing or padding).
        P: ``(P, M, 3, 4)`` projection matrices (zeros for padding).
        normalized_xy: ``(P, M, J, 2)`` keypoints in normalized image coordinates ``K⁻¹ x``.
        Rt: ``(P, M, 3, 4)`` ``[R | t]`` in a normalized world frame, for conditioning.
        centers: ``(P, M, 3)`` camera centres (world).
        members: ``(P, M)`` pose index, -1 for padding.
        size: ``(P, M)`` the unit of image distances in each slot's view, px: the median size
            of the people detected in it (:func:`mvm.core.image_units.view_sizes`; 1 for padding).
        world_scale, world_offset: ``X_world = scale · X_normalized + offset``.
    """

    xy: np.ndarray
    conf: np.ndarray
    P: np.ndarray
    normalized_xy: np.ndarray
    Rt: np.ndarray
    centers: np.ndarray
    members: np.ndarray
    world_scale: float
    world_offset: np.ndarray
    size: np.ndarray

    def rows(self, rows: slice) -> GroupObservations:
        """The observations of the groups ``rows`` (views of these arrays, not copies)."""
        return GroupObservations(self.xy[rows], self.conf[rows], self.P[rows], self.normalized_xy[rows],
                                 self.Rt[rows], self.centers[rows], self.members[rows], self.world_scale,
                                 self.world_offset, self.size[rows])


def gather_groups(cameras: Cameras, poses: Poses2D, groups: list[np.ndarray],
                  keypoint_threshold: float) -> GroupObservations:
    """Pad the groups' keypoints and cameras into ``(P, M, ...)`` arrays."""
    P_count = len(groups)
    M = max((len(g) for g in groups), default=0)
    members = np.full((P_count, M), -1)
    for p, g in enumerate(groups):
        members[p, :len(g)] = g
    pad = members < 0
    idx = np.where(pad, 0, members)
    kp = poses.keypoints[idx]                                           # (P, M, J, 3)
    conf = np.where(pad[..., None] | (kp[..., 2] < keypoint_threshold), 0.0, kp[..., 2])
    views = poses.view[idx]
    centers_all = cameras.centers
    offset = centers_all.mean(axis=0)
    scale = float(np.sqrt(((centers_all - offset) ** 2).sum(1).mean())) or 1.0
    Rt = np.concatenate([cameras.R, ((cameras.t + cameras.R @ offset) / scale)[:, :, None]], axis=2)
    K_inv = np.linalg.inv(cameras.K)
    homogeneous = np.concatenate([kp[..., :2], np.ones(kp.shape[:-1] + (1,))], axis=-1)
    normalized = np.matmul(homogeneous, K_inv[views].transpose(0, 1, 3, 2))[..., :2]
    Pm = np.where(pad[..., None, None], 0.0, cameras.P[views])
    size = np.where(pad, 1.0, view_sizes(poses, keypoint_threshold)[idx])
    return GroupObservations(kp[..., :2], conf, Pm, normalized, Rt[views], centers_all[views],
                             members, scale, offset, size)


@dataclass
class Triangulation:
    """Per-joint triangulation of ``P`` groups.

    Attributes:
        X: ``(P, J, 3)`` world points, NaN where not reconstructed.
        inliers: ``(P, M, J)`` bool, the 2D keypoints used.
        valid: ``(P, M, J)`` bool, the 2D keypoints available (inliers + outliers).
        parallax_deg: ``(P, J)`` largest angle between inlier rays.
        threshold: ``(P,)`` the RANSAC inlier threshold each group got, person sizes.
        hypotheses: the scored RANSAC hypotheses, where asked for (``keep_hypotheses``): the
            same groups triangulated again at another threshold select from them.
    """

    X: np.ndarray
    inliers: np.ndarray
    valid: np.ndarray
    parallax_deg: np.ndarray
    threshold: np.ndarray
    hypotheses: Hypotheses | None = None


@dataclass
class Hypotheses:
    """The RANSAC hypotheses of every joint of ``P`` groups, scored in ``S`` view slots.

    Attributes:
        err: ``(P, S, J, H)`` reprojection errors, person sizes.
        ok: ``(P, S, J, H)`` bool, the keypoint is available and the point in front of its camera.
        point: ``(P, J, H)`` bool, the hypothesis is a point (finite).
        slots: ``(P, S)`` the view slots scored (:func:`spread_slots`), or None: every slot.
    """

    err: np.ndarray
    ok: np.ndarray
    point: np.ndarray
    slots: np.ndarray | None

    def rows(self, rows: slice) -> Hypotheses:
        """The hypotheses of the groups ``rows`` (views, not copies)."""
        return Hypotheses(self.err[rows], self.ok[rows], self.point[rows],
                          None if self.slots is None else self.slots[rows])

    @staticmethod
    def concatenate(parts: list[Hypotheses]) -> Hypotheses:
        """The hypotheses of consecutive groups, ``parts`` scored with the same ``S`` and ``H``."""
        slots = None if parts[0].slots is None else np.concatenate([h.slots for h in parts])
        return Hypotheses(*(np.concatenate([getattr(h, f) for h in parts]) for f in ("err", "ok", "point")), slots)


@functools.lru_cache(maxsize=64)
def _pair_table(M: int) -> np.ndarray:
    """``(C(M, 2), 2)`` the pairs ``i < j`` of ``M`` ranks ordered by ``j``: the first ``C(n, 2)``
    are exactly the pairs of the first ``n`` ranks. Made once per ``M`` (read-only)."""
    j, i = np.divmod(np.arange(M * M), M)
    table = np.stack([i, j], -1)[i < j]
    table.flags.writeable = False
    return table


def _sample_pairs(valid: np.ndarray, hypotheses: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of distinct valid views. ``valid: (P, M, J)`` -> two ``(P, J, H)`` view indices.

    A joint with ``n`` valid views has ``C(n, 2)`` distinct pairs: where they are at most
    ``hypotheses``, every pair is a hypothesis (cycled to fill ``H``); elsewhere ``hypotheses``
    random pairs are drawn from ``rng``, a ``numpy.random.Generator`` or the seed of one. ``H``
    is ``hypotheses``, or ``max C(n, 2)`` when every joint is enumerated (and no random number
    is drawn: ``numpy.random``, 30 ms to import, is then never loaded)."""
    order = np.argsort(~valid, axis=1, kind="stable").transpose(0, 2, 1)    # (P, J, M) valid first
    count = valid.sum(axis=1)                                                # (P, J)
    pairs = count * (count - 1) // 2
    enumerate_all = pairs <= hypotheses
    # Groups of one view (min_group_size = 1) have no pair: both draws are that view, the
    # hypothesis is degenerate (NaN) and the joint stays unreconstructed.
    if enumerate_all.all():
        shape = count.shape + (max(1, int(pairs.max(initial=0))),)
        a = b = np.zeros(shape, dtype=int)
    else:
        n = np.minimum(np.maximum(count, 2), valid.shape[1])[..., None]
        shape = count.shape + (hypotheses,)
        rng = rng if hasattr(rng, "random") else np.random.default_rng(rng)
        a = np.floor(rng.random(shape) * n).astype(int)
        b = np.floor(rng.random(shape) * (n - 1)).astype(int)
        b = b + (b >= a)
        a = np.minimum(a, n - 1)
        b = np.minimum(b, n - 1)
    table = _pair_table(valid.shape[1])
    if len(table):
        slot = np.arange(shape[-1]) % np.maximum(pairs, 1)[..., None]        # (P, J, H)
        a = np.where(enumerate_all[..., None], table[slot, 0] * (pairs[..., None] > 0), a)
        b = np.where(enumerate_all[..., None], table[slot, 1] * (pairs[..., None] > 0), b)
    p, j = np.ogrid[:shape[0], :shape[1]]
    return order[p[..., None], j[..., None], a], order[p[..., None], j[..., None], b]


def _reprojection_errors(X: np.ndarray, obs: GroupObservations) -> tuple[np.ndarray, np.ndarray]:
    """``X: (P, J, H, 3)`` world points -> reprojection errors ``(P, M, J, H)`` in person sizes
    (pixels divided by the slot's ``obs.size``) and depths."""
    Pn, J, H, _ = X.shape
    M = obs.P.shape[1]
    homogeneous = np.concatenate([X, np.ones((Pn, J, H, 1))], axis=-1).reshape(Pn, J * H, 4)
    x = np.matmul(obs.P.reshape(Pn, M * 3, 4), homogeneous.transpose(0, 2, 1)).reshape(Pn, M, 3, J, H)
    depth = x[:, :, 2]
    with np.errstate(divide="ignore", invalid="ignore"):       # in place: two arrays of (P, M, J, H), not eight
        du = np.divide(x[:, :, 0], depth)
        du -= obs.xy[..., 0, None]
        du *= du
        dv = np.divide(x[:, :, 1], depth)
        dv -= obs.xy[..., 1, None]
        dv *= dv
        du += dv
        del dv
        np.sqrt(du, out=du)
        du /= obs.size[:, :, None, None]
    return du, depth


def ransac_triangulate(obs: GroupObservations, threshold: float | np.ndarray, hypotheses: int,
                       min_views: int, min_parallax_deg: float,
                       rng: np.random.Generator | int | None = None, use_ransac: bool = True,
                       initial: np.ndarray | None = None, max_views: int | None = None,
                       hypotheses_scored: Hypotheses | None = None, keep_hypotheses: bool = False) -> Triangulation:
    """Triangulate every joint of every group with RANSAC over two-view DLT hypotheses.

    A joint with at most ``hypotheses`` pairs of views tries each pair once; others draw
    ``hypotheses`` random pairs (:func:`_sample_pairs`). Each hypothesis is scored by MSAC,
    ``Σ min(e², thr²)`` over the available keypoints, ``e`` the reprojection error in person
    sizes (:mod:`mvm.core.image_units`) and ``thr`` the group's ``threshold`` (one number, or
    ``(P,)``); the best one's inliers (``e < thr``, in front of the camera) are re-triangulated
    with confidence weights, twice. A joint with fewer than ``min_views`` inliers or whose inlier
    rays span less than ``min_parallax_deg`` is left NaN. With ``use_ransac=False`` every
    available keypoint is an inlier (the paper's "w/o RANSAC" columns).

    ``initial: (P, J, 3)`` world points (NaN: none) join the two-view hypotheses, e.g. a previous
    triangulation of nearly the same groups: few random hypotheses then suffice. ``rng``: a
    ``numpy.random.Generator`` or the seed of one (None: 0), made only if pairs are drawn.
    ``max_views``: groups of more views (a person seen in thousands of frames of a long video)
    draw and score their hypotheses on that many well-spread views of each person
    (:func:`spread_slots`); the inliers are then those of the best hypothesis's weighted DLT in
    every view, and the refits use them all. Cost: ``P · (M + max_views · H) · J``, never
    ``P · M · J · H``. None: every view. ``hypotheses_scored``: the :class:`Hypotheses` of a call
    on the same observations and settings (with ``keep_hypotheses``), at any threshold: they are
    not drawn and scored again, and the result is the one a call of its own gives.

    The groups are triangulated a few at a time (:data:`TRIANGULATION_CHUNK`), the random pairs
    of all of them drawn at once: the result does not depend on the chunks.
    """
    rng = 0 if rng is None else rng
    valid = obs.conf > 0                                                    # (P, M, J)
    Pn, M, J = valid.shape
    threshold = np.broadcast_to(np.asarray(threshold, dtype=float), (Pn,))
    if Pn == 0 or M == 0:
        empty = np.zeros((Pn, J, 3)) * np.nan
        return Triangulation(empty, valid.copy(), valid, np.zeros((Pn, J)), threshold)
    scored, slots, pairs, H = hypotheses_scored, None, None, 0
    if use_ransac and scored is not None:
        slots, H = scored.slots, scored.err.shape[-1]
    elif use_ransac:
        slots, pairs, H = _draw_pairs(obs.conf, hypotheses, rng, max_views, initial is not None)
    S = M if slots is None else slots.shape[1]
    step = max(1, TRIANGULATION_CHUNK // (J * (10 * M + 3 * S * H)))
    parts = []
    for rows in (slice(s, s + step) for s in range(0, Pn, step)):
        parts.append(_triangulate_rows(
            obs.rows(rows), threshold[rows], min_views, min_parallax_deg, use_ransac,
            None if initial is None else initial[rows], None if slots is None else slots[rows],
            None if pairs is None else (pairs[0][rows], pairs[1][rows]),
            None if scored is None else scored.rows(rows)))
    tri = Triangulation(*(np.concatenate([getattr(t, f) for t, _ in parts])
                          for f in ("X", "inliers", "valid", "parallax_deg")), threshold)
    if keep_hypotheses and use_ransac:
        tri.hypotheses = scored if scored is not None else Hypotheses.concatenate([h for _, h in parts])
    return tri


def _draw_pairs(conf: np.ndarray, hypotheses: int, rng, max_views: int | None, initial: bool
                ) -> tuple[np.ndarray | None, tuple[np.ndarray, np.ndarray], int]:
    """The hypotheses of :func:`ransac_triangulate`, drawn for all groups ``conf: (P, M, J)`` at
    once: the view slots they are scored in (``(P, S)`` spread slots where ``M > max_views``,
    else None: every slot), the pairs of those slots (:func:`_sample_pairs`) and ``H``, the
    hypotheses per joint (one more with ``initial`` points)."""
    valid = conf > 0
    slots = spread_slots(conf, max_views) if max_views is not None and conf.shape[1] > max_views else None
    if slots is not None:
        valid = valid[np.arange(len(conf))[:, None], np.maximum(slots, 0)] & (slots >= 0)[..., None]   # (P, S, J)
    pairs = _sample_pairs(valid, hypotheses, rng)
    return slots, pairs, pairs[0].shape[-1] + initial


#: Entries of the largest arrays of a triangulation of a few groups: a group counts
#: ``J · (10 M + 3 S H)``, the DLT terms of its ``M`` view slots and the projections of its ``H``
#: hypotheses in ``S`` of them. The arrays stay under 8 MB whatever the length of the video or the
#: number of groups: beyond the allocator's reuse threshold (32 MB) an array costs its page
#: faults anew at every call, more than the arithmetic on it.
TRIANGULATION_CHUNK = 2**20


def _triangulate_rows(obs: GroupObservations, threshold: np.ndarray, min_views: int, min_parallax_deg: float,
                      use_ransac: bool, initial: np.ndarray | None, slots: np.ndarray | None,
                      pairs: tuple[np.ndarray, np.ndarray] | None, scored: Hypotheses | None
                      ) -> tuple[Triangulation, Hypotheses | None]:
    """:func:`ransac_triangulate` of a few groups, ``threshold: (P,)``: their triangulation and
    hypotheses. Hypotheses are ``scored`` already, or made from the view ``pairs`` (two
    ``(P, J, H)`` slot indices, :func:`_sample_pairs`) and ``initial: (P, J, 3)``, scored in every
    view slot or, with ``slots: (P, S)``, in those (:func:`_spread_ransac_inliers`)."""
    valid = obs.conf > 0                                                    # (P, M, J)
    terms = dlt_terms(obs.normalized_xy.transpose(0, 2, 1, 3), obs.Rt[:, None])  # (10, P, J, M)
    if not use_ransac:
        inliers = valid.copy()
    elif slots is not None:
        inliers, scored = _spread_ransac_inliers(obs, valid, threshold, pairs, initial, slots, scored)
    else:
        scored = scored or _score_hypotheses(obs, valid, terms, pairs, initial)
        inliers = _best_inliers(scored, valid, threshold)

    weights = np.where(inliers, obs.conf, 0.0).transpose(0, 2, 1)             # (P, J, M)
    solved = None
    for _ in range(2 if use_ransac else 1):
        solved = _refit(terms, weights, solved)
        X = solved[1]                                                       # (P, J, 3)
        if not use_ransac:
            break
        err, depth = _reprojection_errors(X[:, :, None] * obs.world_scale + obs.world_offset, obs)
        refreshed = valid & (err[..., 0] < threshold[:, None, None]) & (depth[..., 0] > 0)
        keep = refreshed.sum(axis=1) >= min_views
        inliers = np.where(keep[:, None, :], refreshed, inliers)
        weights = np.where(inliers, obs.conf, 0.0).transpose(0, 2, 1)
    X = _refit(terms, weights, solved)[1] * obs.world_scale + obs.world_offset

    directions = X[:, None] - obs.centers[:, :, None]                          # (P, M, J, 3)
    directions /= np.maximum(np.linalg.norm(directions, axis=-1, keepdims=True), 1e-12)
    parallax = ray_spread_deg(directions.transpose(0, 2, 1, 3), inliers.transpose(0, 2, 1))
    good = (inliers.sum(axis=1) >= min_views) & (parallax >= min_parallax_deg) & np.isfinite(X).all(-1)
    X[~good] = np.nan
    inliers &= good[:, None, :]
    return Triangulation(X, inliers, valid, parallax, threshold), scored


def _refit(terms: np.ndarray, weights: np.ndarray, previous: tuple | None) -> tuple[np.ndarray, np.ndarray]:
    """``(weights, X)``: the weighted DLT of ``weights: (P, J, M)``, or ``previous`` (the same
    pair from the last refit) when the weights have not changed, as the inliers usually do not
    between refits: the same numbers, one solve fewer."""
    if previous is not None and np.array_equal(previous[0], weights):
        return previous
    return weights, weighted_dlt(terms, weights)


def _score_hypotheses(obs: GroupObservations, valid: np.ndarray, terms: np.ndarray,
                      pairs: tuple[np.ndarray, np.ndarray], initial: np.ndarray | None,
                      slots: np.ndarray | None = None) -> Hypotheses:
    """Two-view DLT hypotheses of every joint and their reprojection errors in every view slot
    of ``obs`` (:class:`Hypotheses`). ``terms: (10, P, J, M)`` the views' :func:`mvm.core.geometry.dlt_terms`;
    ``pairs``: two ``(P, J, H)`` slot indices (:func:`_sample_pairs`); ``initial: (P, J, 3)``
    world points join the two-view hypotheses; ``slots``: recorded as the scored slots."""
    a, b = pairs
    # A pair of one view twice (a joint seen once) has no point: NaN, never a better hypothesis.
    p, j = np.ogrid[:a.shape[0], :a.shape[1]]
    p, j = p[..., None], j[..., None]
    X_h = solve_dlt(terms[:, p, j, a] + terms[:, p, j, b], a != b)
    if initial is not None:
        X_h = np.concatenate([X_h, (initial[:, :, None] - obs.world_offset) / obs.world_scale], axis=2)
    err, depth = _reprojection_errors(X_h * obs.world_scale + obs.world_offset, obs)  # (P, M, J, H)
    ok = valid[..., None] & (depth > 0) & np.isfinite(err)
    return Hypotheses(err, ok, np.isfinite(X_h).all(-1), slots)


def _best_inliers(scored: Hypotheses, valid: np.ndarray, threshold: np.ndarray) -> np.ndarray:
    """The inliers ``(P, M, J)`` of the best hypothesis of every joint (MSAC score) at the
    groups' ``threshold: (P,)`` (person sizes); ``valid: (P, M, J)`` the slots scored."""
    err, ok = scored.err, scored.ok
    threshold = threshold[:, None, None, None]
    cost = np.minimum(err, threshold)                                         # (P, M, J, H)
    cost *= cost
    np.copyto(cost, np.where(valid, threshold[..., 0] ** 2, 0.0)[..., None], where=~ok)   # an outlier, or no keypoint
    cost = cost.sum(axis=1)                                                   # (P, J, H)
    cost[~scored.point] = np.inf
    best = np.argmin(cost, axis=-1)[:, None, :, None]                         # (P, 1, J, 1)
    return (np.take_along_axis(ok, best, -1) & (np.take_along_axis(err, best, -1) < threshold))[..., 0]


#: The median of the length of a two-dimensional standard normal error: ``sqrt(2 ln 2)``.
RAYLEIGH_MEDIAN = float(np.sqrt(2 * np.log(2)))


def residual_sigma(obs: GroupObservations, tri: Triangulation, block: np.ndarray, blocks: int) -> np.ndarray:
    """The detector's noise in each block (scene, or rig instant) of groups, measured from the
    triangulation: the per-axis standard deviation ``σ`` of the keypoints' errors, in person
    sizes, whose inliers' reprojection errors have the median they have.

    The errors of a two-dimensional Gaussian have a Rayleigh distribution; the inliers are
    those below the threshold ``t``, so their median ``m`` is the one of a Rayleigh cut at
    ``t``: ``σ`` solves ``2 F(m) = F(t)``, ``F(x) = 1 - exp(-x² / 2σ²)`` (bisection). Each
    error is first scaled by ``sqrt(2n / (2n - 3))`` for the 3 coordinates its joint's ``n``
    inliers fitted. ``block: (P,)`` block of each group in ``[0, blocks)`` -> ``(blocks,)``,
    NaN for a block without any joint of three inliers or more (two views leave the noise
    unmeasured), inf where the errors fill the threshold evenly (no Gaussian has them).
    """
    X = tri.X                                                                 # (P, J, 3)
    if not len(X):
        return np.full(blocks, np.nan)
    err, _ = _reprojection_errors(np.nan_to_num(X)[:, :, None], obs)   # (P, M, J, 1)
    n = tri.inliers.sum(axis=1)                                               # (P, J)
    used = tri.inliers & (n >= 3)[:, None, :] & np.isfinite(X).all(-1)[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        scaled = err[..., 0] * np.sqrt(2 * n / (2 * n - 3))[:, None, :]
    m = medians_by(scaled[used], block[np.nonzero(used)[0]], blocks)
    cut = np.full(blocks, np.inf)
    np.minimum.at(cut, block, tri.threshold)                                  # the block's threshold
    return rayleigh_sigma(m, cut)


def rayleigh_sigma(m: np.ndarray, cut: np.ndarray) -> np.ndarray:
    """The deviation ``σ`` per axis of a two-dimensional Gaussian error whose lengths, kept below
    ``cut``, have the median ``m``: ``2 F(m) = F(cut)``, ``F(x) = 1 - exp(-x² / 2σ²)``, by
    bisection. ``m, cut: (B,)`` -> ``(B,)``; NaN where ``m`` is, inf where ``2 m² >= cut²`` (no
    Gaussian has such errors); ``cut = inf``: ``m`` over :data:`RAYLEIGH_MEDIAN`.

    >>> rayleigh_sigma(np.array([RAYLEIGH_MEDIAN, 1.0]), np.array([np.inf, 1.2])).round(3).tolist()
    [1.0, inf]
    """
    m, cut = np.asarray(m, dtype=float), np.asarray(cut, dtype=float)
    lo, hi = np.log(np.maximum(m, 1e-12) / RAYLEIGH_MEDIAN), np.log(np.maximum(m, 1e-12)) + 10.0
    for _ in range(50):                                                       # bisection on log σ
        mid = (lo + hi) / 2
        sigma2 = 2 * np.exp(2 * mid)
        below = 2 * -np.expm1(-m * m / sigma2) > -np.expm1(-cut * cut / sigma2)   # σ too small
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    sigma = np.exp((lo + hi) / 2)
    return np.where(2 * m * m >= cut * cut, np.inf, sigma)                     # no Gaussian fits (NaN: no m)




def spread_slots(conf: np.ndarray, count: int) -> np.ndarray:
    """``count`` of each group's view slots, well spread along the group and confident:
    the slots holding keypoints are cut into ``count`` runs of consecutive slots (a group's
    poses come in frame order: runs along the video, so spread in parallax), and each run gives
    its slot of largest summed confidence. ``conf: (P, M, J)`` -> ``(P, count)`` slot indices in
    increasing order, -1 for padding (a group of fewer slots).

    Six slots of one group, the fourth empty, cut into two runs:

    >>> conf = np.array([[1.0, 3.0, 2.0, 0.0, 5.0, 1.0]])[..., None]
    >>> spread_slots(conf, 2)
    array([[1, 4]])
    >>> spread_slots(np.array([[0.0, 2.0, 0.0, 0.0, 1.0, 0.0]])[..., None], 3)   # two slots hold keypoints
    array([[ 1,  4, -1]])
    """
    weight = conf.sum(-1)                                                   # (P, M)
    present = weight > 0
    n = present.sum(1, keepdims=True)
    run = np.where(present, (np.cumsum(present, 1) - 1) * count // np.maximum(n, 1), count)
    key = run - weight / (weight.max(initial=0.0) + 1.0)                    # in a run, the most confident first
    order = np.argsort(key, axis=1, kind="stable")
    sorted_run = np.take_along_axis(run, order, 1)
    first = np.ones(sorted_run.shape, dtype=bool)
    first[:, 1:] = sorted_run[:, 1:] != sorted_run[:, :-1]
    M = conf.shape[1]
    slots = np.sort(np.where(first & (sorted_run < count), order, M), axis=1)[:, :count]
    return np.where(slots < M, slots, -1)


def take_slots(obs: GroupObservations, slots: np.ndarray) -> GroupObservations:
    """The observations of the view ``slots: (P, S)`` of each group (-1: padding)."""
    pad = slots < 0
    p = np.arange(len(slots))[:, None]
    idx = np.where(pad, 0, slots)
    return GroupObservations(obs.xy[p, idx], np.where(pad[..., None], 0.0, obs.conf[p, idx]),
                             np.where(pad[..., None, None], 0.0, obs.P[p, idx]), obs.normalized_xy[p, idx],
                             obs.Rt[p, idx], obs.centers[p, idx], np.where(pad, -1, obs.members[p, idx]),
                             obs.world_scale, obs.world_offset, np.where(pad, 1.0, obs.size[p, idx]))


def _spread_ransac_inliers(obs: GroupObservations, valid: np.ndarray, threshold: np.ndarray,
                           pairs: tuple[np.ndarray, np.ndarray] | None, initial: np.ndarray | None,
                           slots: np.ndarray, scored: Hypotheses | None = None) -> tuple[np.ndarray, Hypotheses]:
    """The RANSAC of :func:`ransac_triangulate` on the well-spread view ``slots: (P, S)`` of
    each group (:func:`spread_slots`), whose inliers' weighted DLT then gives the inliers
    ``(P, M, J)`` among all the views (reprojection error below each group's ``threshold: (P,)``,
    in person sizes, in front of the camera); and the hypotheses scored (``scored``, where
    given; else made from ``pairs`` of those slots and ``initial``, as :func:`_score_hypotheses`)."""
    sub = take_slots(obs, slots)
    terms = dlt_terms(sub.normalized_xy.transpose(0, 2, 1, 3), sub.Rt[:, None])     # (10, P, J, S)
    if scored is None:
        scored = _score_hypotheses(sub, sub.conf > 0, terms, pairs, initial, slots)
    chosen = _best_inliers(scored, sub.conf > 0, threshold)
    X = weighted_dlt(terms, np.where(chosen, sub.conf, 0.0).transpose(0, 2, 1))       # (P, J, 3) normalized
    err, depth = _reprojection_errors(X[:, :, None] * obs.world_scale + obs.world_offset, obs)
    return valid & (err[..., 0] < threshold[:, None, None]) & (depth[..., 0] > 0), scored
