"""Relative poses of camera pairs from the people they both see (step 1 of
:mod:`mvm.rig.calibrate`; no I/O).

At every instant, every pose of camera ``a`` paired with every pose of camera ``b`` is a
candidate person correspondence: a correct pairing gives up to 17 point correspondences, a
wrong one outliers. A pairing that repeats an earlier one (one of its poses within
``REPEAT_HEIGHT`` of its height of that pairing's: a person standing still, seen by the one
camera or both) is counted once, so a static bystander seen in every frame weighs as one
instant, not a hundred, and a still pose paired with a moving one (which cannot be the same
person) is not counted at all; once the pair's relative pose is found, every pairing it explains,
repeats included, links the people for the bundle adjustment. The essential matrix is
estimated robustly on the undistorted, normalized joints: hypotheses from two candidate
pairings at once (``cv2.findEssentialMat`` with a short RANSAC on their joints — a good draw
needs only two correct pairings, not five correct points), each scored by the joints it
explains, the best refitted with ``cv2.findEssentialMat`` (RANSAC) on the pairings it accepts
and decomposed by ``cv2.recoverPose``. A joint agrees with a hypothesis within a Sampson error
of ``INLIER_HEIGHT`` of its pairing's height (the detectors' noise grows with the person's
image size: a nano model on a real person is off by 2–3 % of its height), and never less than
``INLIER_PX``.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from mvm.core.geometry import skew

#: A joint agrees with an essential matrix within this Sampson error at least. [px]
INLIER_PX = 6.0
#: ... and within this fraction of its pairing's height (the geometric mean of its two poses'
#: heights in pixels). [1]
INLIER_HEIGHT = 0.03
#: A candidate pairing repeats an earlier one when one of its poses lies within this fraction of
#: its height (median over the joints) of that pairing's pose in the same camera. [1]
REPEAT_HEIGHT = 0.02
#: A candidate pairing is accepted when at least this fraction of its common joints agree.
PAIRING_INLIER_FRACTION = 0.6
#: Fewest common joints of a usable candidate pairing.
MIN_PAIR_JOINTS = 8
#: Hypotheses drawn per camera pair, at most.
HYPOTHESES = 300
#: Hypotheses stop once a draw of two accepted pairings had this probability, after at least
#: ``MIN_HYPOTHESES``.
CONFIDENCE = 0.9999
MIN_HYPOTHESES = 30
#: RANSAC iterations of one hypothesis (on the joints of two pairings: few outliers when both
#: pairings are right, and a wrong draw is not worth more).
HYPOTHESIS_ITERATIONS = 32
#: Fewest accepted pairings for a camera pair to be used.
MIN_PAIRINGS = 5

@dataclass
class PairPose:
    """The relative pose of cameras ``a`` and ``b``: ``x_b = R x_a + t`` (``|t| = 1``).

    Attributes:
        pose_a, pose_b: ``(M,)`` the accepted pairings (indices into the detections).
        error_px: median Sampson error of their joints.
    """

    a: int
    b: int
    R: np.ndarray
    t: np.ndarray
    pose_a: np.ndarray
    pose_b: np.ndarray
    error_px: float


@dataclass
class PairCount:
    """Why a camera pair has no relative pose: its ``candidates`` (pairings with enough common
    joints), how many of them are ``distinct`` (not repeats of an earlier one)."""

    candidates: int
    distinct: int



def aligned_pairs(frame_a: np.ndarray, frame_b: np.ndarray, lag: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Every pair of poses ``(i, j)`` with ``frame_a[i] == frame_b[j] + lag``. ``frame_a: (A,)``,
    ``frame_b: (B,)`` -> ``(ia (M,), jb (M,))``."""
    order = np.argsort(frame_a, kind="stable")
    sorted_a = frame_a[order]
    target = frame_b + lag
    lo, hi = np.searchsorted(sorted_a, target), np.searchsorted(sorted_a, target, "right")
    counts = hi - lo
    jb = np.repeat(np.arange(len(frame_b)), counts)
    within = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    return order[np.repeat(lo, counts) + within], jb


def sampson(E: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Sampson error of ``x_b^T E x_a = 0`` for ``xa, xb: (..., 2)`` (in their units) -> ``(...)``."""
    ha = np.concatenate([xa, np.ones(xa.shape[:-1] + (1,))], -1)
    hb = np.concatenate([xb, np.ones(xb.shape[:-1] + (1,))], -1)
    Ea = ha @ E.T
    Eb = hb @ E
    num = np.einsum("...i,...i->...", hb, Ea)
    den = Ea[..., 0] ** 2 + Ea[..., 1] ** 2 + Eb[..., 0] ** 2 + Eb[..., 1] ** 2
    return np.abs(num) / np.sqrt(np.maximum(den, 1e-18))


def _score(E: np.ndarray, xa: np.ndarray, xb: np.ndarray, ok: np.ndarray, threshold: float | np.ndarray
           ) -> tuple[int, np.ndarray, np.ndarray]:
    """Joints (in accepted pairings) explained by ``E``; ``(count, accepted (M,), joint inliers (M, 17))``."""
    inlier = (sampson(E, xa, xb) < np.reshape(threshold, (-1, 1))) & ok
    accepted = inlier.sum(1) >= PAIRING_INLIER_FRACTION * np.maximum(ok.sum(1), 1)
    return int(inlier[accepted].sum()), accepted, inlier & accepted[:, None]


def _split(E: np.ndarray | None) -> list[np.ndarray]:
    """The 3x3 solutions stacked by ``cv2.findEssentialMat``."""
    if E is None or E.size < 9:
        return []
    return [E[3 * k:3 * k + 3] for k in range(E.shape[0] // 3)]


def essential_from_pairings(xa: np.ndarray, xb: np.ndarray, ok: np.ndarray, threshold: float | np.ndarray,
                            rng: np.random.Generator, hypotheses: int = HYPOTHESES
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Robust essential matrix of candidate pairings (module docstring, step 1).

    Hypotheses: ``cv2.findEssentialMat`` (five points, a short RANSAC) on the joints of two
    candidate pairings, each scored by the joints it explains in accepted pairings; drawing
    stops once a draw of two accepted pairings had a ``CONFIDENCE`` chance. The best is
    refitted by ``cv2.findEssentialMat`` (RANSAC) on the joints it explains.

    Args:
        xa, xb: ``(M, 17, 2)`` normalized joints of the ``M`` candidate pairings; ok: ``(M, 17)``
            present in both.
        threshold: inlier Sampson error in normalized units, one or ``(M,)`` (one per pairing;
            the RANSAC fits take their median).
    Returns:
        ``(E (3, 3), accepted (M,), joint inliers (M, 17))`` or None when no hypothesis explains
        ``MIN_PAIRINGS`` pairings.
    """
    usable = np.flatnonzero(ok.sum(1) >= MIN_PAIR_JOINTS)
    if len(usable) < MIN_PAIRINGS:
        return None
    threshold = np.broadcast_to(np.asarray(threshold, dtype=float), (len(xa),))
    fit = float(np.median(threshold[usable]))
    best = (0, None, None, None)
    for n, (i, j) in enumerate(rng.choice(usable, (hypotheses, 2))):
        if best[2] is not None:
            good = (best[2][usable].sum() / len(usable)) ** 2
            if good > 0 and n >= MIN_HYPOTHESES and n >= np.log(1 - CONFIDENCE) / np.log1p(-min(good, 0.999)):
                break
        if i == j:
            continue
        pa = np.concatenate([xa[i][ok[i]], xa[j][ok[j]]])
        pb = np.concatenate([xb[i][ok[i]], xb[j][ok[j]]])
        E, _ = cv2.findEssentialMat(pa, pb, np.eye(3), cv2.RANSAC, 0.999, fit, HYPOTHESIS_ITERATIONS)
        for candidate in _split(E):
            count, accepted, inlier = _score(candidate, xa, xb, ok, threshold)
            if count > best[0]:
                best = (count, candidate, accepted, inlier)
    if best[1] is None or best[2].sum() < MIN_PAIRINGS:
        return None
    _, E, accepted, inlier = best
    refit, _ = cv2.findEssentialMat(xa[inlier], xb[inlier], np.eye(3), cv2.RANSAC, 0.999, fit)
    for candidate in _split(refit):
        count, acc, inl = _score(candidate, xa, xb, ok, threshold)
        if count >= best[0]:
            best = (count, candidate, acc, inl)
    return best[1], best[2], best[3]


def relative_pose(xa: np.ndarray, xb: np.ndarray, ok: np.ndarray, threshold: float | np.ndarray,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """``(R, t, accepted (M,), joint inliers (M, 17))`` with ``x_b = R x_a + t`` (``|t| = 1``)
    from candidate pairings (:func:`essential_from_pairings`), or None."""
    found = essential_from_pairings(xa, xb, ok, threshold, rng)
    if found is None:
        return None
    E, accepted, inlier = found
    _, R, t, _ = cv2.recoverPose(E, xa[inlier].reshape(-1, 1, 2), xb[inlier].reshape(-1, 1, 2), np.eye(3))
    return R, t.ravel(), accepted, inlier


def pose_heights(keypoints: np.ndarray) -> np.ndarray:
    """Each pose's height in pixels: the vertical extent of its present joints.
    ``keypoints: (N, 17, 3)`` -> ``(N,)`` (0 without two joints)."""
    y = np.where(keypoints[..., 2] > 0, keypoints[..., 1], np.nan)
    count = (keypoints[..., 2] > 0).sum(1)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        height = np.nanmax(y, 1) - np.nanmin(y, 1)
    return np.where(count >= 2, np.nan_to_num(height), 0.0)


def distinct_pairings(ka: np.ndarray, kb: np.ndarray, height: np.ndarray, ok: np.ndarray, instant: np.ndarray
                      ) -> np.ndarray:
    """The candidate pairings that repeat no pairing of an earlier instant (module docstring).

    ``ka, kb: (M, 17, 2)`` their poses in pixels, ``height: (M,)``, ``ok: (M, 17)``, ``instant:
    (M,)`` -> ``(M,)`` bool."""
    keep = np.zeros(len(ka), bool)
    for t in np.unique(instant):
        now, kept = np.flatnonzero(instant == t), np.flatnonzero(keep)
        if not len(kept):
            keep[now] = True
            continue
        both = ok[now, None] & ok[None, kept]                                       # (n, K, 17)
        d = np.minimum(np.linalg.norm(ka[now, None] - ka[None, kept], axis=-1),
                       np.linalg.norm(kb[now, None] - kb[None, kept], axis=-1))
        d = np.sort(np.where(both, d, np.inf), axis=-1)
        count = both.sum(-1)
        median = np.take_along_axis(d, np.maximum(count - 1, 0)[..., None] // 2, -1)[..., 0]
        repeat = ((count > 0) & (median < REPEAT_HEIGHT * height[now, None])).any(1)
        keep[now] = ~repeat
    return keep


def pair_poses(keypoints: np.ndarray, x: np.ndarray, present: np.ndarray, camera: np.ndarray, instant: np.ndarray,
               focal: np.ndarray, rng: np.random.Generator
               ) -> tuple[dict[tuple[int, int], PairPose], dict[tuple[int, int], PairCount]]:
    """The relative pose of every camera pair that shares enough distinct people (module docstring).

    Args:
        keypoints: ``(N, 17, 3)`` undistorted poses (pixels); x: ``(N, 17, 2)`` normalized joints;
        present: ``(N, 17)`` the joints to use; camera, instant: ``(N,)``.
        focal: ``(V,)`` focal lengths (px), for the pixel thresholds.
    Returns:
        ``(pairs, counts)``: the relative poses found, and the candidate and distinct pairings of
        every camera pair (:class:`PairCount`).
    """
    out, counts = {}, {}
    V = len(focal)
    height = pose_heights(np.where(present[..., None], keypoints, 0.0))
    for a in range(V):
        for b in range(a + 1, V):
            rows_a, rows_b = np.flatnonzero(camera == a), np.flatnonzero(camera == b)
            ia, jb = aligned_pairs(instant[rows_a], instant[rows_b])
            ia, jb = rows_a[ia], rows_b[jb]
            ok = present[ia] & present[jb]
            usable = ok.sum(1) >= MIN_PAIR_JOINTS
            ia, jb, ok = ia[usable], jb[usable], ok[usable]
            h = np.sqrt(height[ia] * height[jb])
            distinct = distinct_pairings(keypoints[ia, :, :2], keypoints[jb, :, :2], h, ok, instant[ia])
            counts[a, b] = PairCount(len(ia), int(distinct.sum()))
            scale = np.sqrt(focal[a] * focal[b])
            threshold = np.maximum(INLIER_PX, INLIER_HEIGHT * h) / scale
            found = relative_pose(x[ia[distinct]], x[jb[distinct]], ok[distinct], threshold[distinct], rng)
            if found is None:
                continue
            R, t, _, _ = found                               # the repeats, once it is found, link people too
            E = skew(t) @ R
            _, accepted, inlier = _score(E, x[ia], x[jb], ok, threshold)
            error = float(np.median(sampson(E, x[ia][inlier], x[jb][inlier]))) * scale
            out[a, b] = PairPose(a, b, R, t, ia[accepted], jb[accepted], error)
    return out, counts
