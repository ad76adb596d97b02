"""Calibrating a rig's extrinsics from the people it sees (no calibration object, no I/O).

1. **Camera pairs.** At every instant, every pose of camera ``a`` paired with every pose of
   camera ``b`` is a candidate person correspondence: a correct pairing gives up to 17 point
   correspondences, a wrong one outliers. The essential matrix is estimated robustly on the
   undistorted, normalized joints: hypotheses from two candidate pairings at once
   (``cv2.findEssentialMat`` with a short RANSAC on their joints — a good draw needs only two
   correct pairings, not five correct points), each scored by the joints it explains, the best refitted with
   ``cv2.findEssentialMat`` (RANSAC) on the pairings it accepts and decomposed by
   ``cv2.recoverPose``.
2. **Chaining.** The accepted pairings link 2D poses into persons (connected components at each
   instant). Cameras are placed along a maximum spanning tree of the pairs (weighted by
   accepted pairings) from the reference camera 0: a camera's rotation is its tree parent's
   composed with the pair's, its position the parent's plus the pair's translation direction
   scaled to agree with the joints already triangulated.
3. **Bundle adjustment** over every camera but the reference (rotation vector, translation)
   and every person's joints, optionally every camera's focal length: reprojection errors in
   pixels, ``scipy.optimize.least_squares`` with a Jacobian sparsity, ``x_scale='jac'`` and a
   soft-L1 loss.
4. **World frame from the people:** metres from the bone lengths (the mean adult bones of
   :data:`mvm.core.keypoints.MEAN_BONE_LENGTHS_M`), z up along the standing bodies (mid-ankles
   to mid-shoulders of straight-legged poses; the normal of the floor through their feet when
   they walk about), the origin on the floor (the ankles' level, as
   the pose bank's frame) under the people's mean position, x along the reference camera's
   right axis seen from above.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mvm.core.geometry import triangulate_dlt
from mvm.core.keypoints import INDEX, MEAN_BONE_LENGTHS_M, NUM_JOINTS, bone_lengths
from mvm.rig.bundle_adjustment import bundle_adjust, reprojection_px

#: A joint agrees with an essential matrix within this Sampson error. [px]
INLIER_PX = 6.0
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
#: Instants used at most (evenly spread) for the pairs and the bundle adjustment.
MAX_INSTANTS = 150
#: The calibration has not converged when a camera's median reprojection error exceeds this. [px]
MAX_RESIDUAL_PX = 15.0
#: The floor is fitted through the people's feet (its normal the vertical) when they spread
#: this much (standard deviation) along its narrower direction; else the bodies' axis. [m]
FLOOR_MIN_SPREAD_M = 0.15
#: Straight legs: hip-to-ankle distance at least this fraction of thigh + shank. [1]
STRAIGHT_LEG = 0.9

_ANKLES = [INDEX["left_ankle"], INDEX["right_ankle"]]
_SHOULDERS = [INDEX["left_shoulder"], INDEX["right_shoulder"]]
_HIPS = [INDEX["left_hip"], INDEX["right_hip"]]
_KNEES = [INDEX["left_knee"], INDEX["right_knee"]]


class CalibrationError(ValueError):
    """The people do not determine the cameras: ``camera`` names the index at fault (or None)."""

    def __init__(self, camera: int | None, problem: str):
        self.camera = camera
        self.problem = problem
        super().__init__(problem if camera is None else f"camera {camera}: {problem}")


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
class PeopleCalibration:
    """Extrinsics found from the people.

    Attributes:
        R: ``(V, 3, 3)`` world -> camera rotations; t: ``(V, 3)`` translations (metres).
        residual_px: ``(V,)`` median reprojection error of each camera's joints after adjustment.
        observations: ``(V,)`` joints of each camera in the adjustment.
        tree: ``[(parent, child)]`` the spanning tree the cameras were placed along.
        points: ``(Q, 17, 3)`` the people's joints (world, metres; NaN: not triangulated);
        point_instant: ``(Q,)`` their instants.
        scale_m: metres per unit of the adjustment; converged: the solver met its tolerance (not
            its evaluation limit).
        focal_scale: ``(V,)`` each camera's focal length over the one given (1 unless refined).
    """

    R: np.ndarray
    t: np.ndarray
    residual_px: np.ndarray
    observations: np.ndarray
    tree: list
    points: np.ndarray
    point_instant: np.ndarray
    scale_m: float
    converged: bool
    focal_scale: np.ndarray


def normalized_points(keypoints: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels -> normalized image coordinates ``K^-1 x``. ``keypoints: (N, 17, >=2)``, ``K: (N, 3, 3)``
    or ``(3, 3)`` -> ``(N, 17, 2)``."""
    K = np.broadcast_to(K, (len(keypoints), 3, 3))
    fx, fy, s = K[:, 0, 0, None], K[:, 1, 1, None], K[:, 0, 1, None]
    cx, cy = K[:, 0, 2, None], K[:, 1, 2, None]
    y = (keypoints[..., 1] - cy) / fy
    x = (keypoints[..., 0] - cx - s * y) / fx
    return np.stack([x, y], -1)


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


def _score(E: np.ndarray, xa: np.ndarray, xb: np.ndarray, ok: np.ndarray, threshold: float
           ) -> tuple[int, np.ndarray, np.ndarray]:
    """Joints (in accepted pairings) explained by ``E``; ``(count, accepted (M,), joint inliers (M, 17))``."""
    inlier = (sampson(E, xa, xb) < threshold) & ok
    accepted = inlier.sum(1) >= PAIRING_INLIER_FRACTION * np.maximum(ok.sum(1), 1)
    return int(inlier[accepted].sum()), accepted, inlier & accepted[:, None]


def _split(E: np.ndarray | None) -> list[np.ndarray]:
    """The 3x3 solutions stacked by ``cv2.findEssentialMat``."""
    if E is None or E.size < 9:
        return []
    return [E[3 * k:3 * k + 3] for k in range(E.shape[0] // 3)]


def essential_from_pairings(xa: np.ndarray, xb: np.ndarray, ok: np.ndarray, threshold: float,
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
        threshold: inlier Sampson error in normalized units.
    Returns:
        ``(E (3, 3), accepted (M,), joint inliers (M, 17))`` or None when no hypothesis explains
        ``MIN_PAIRINGS`` pairings.
    """
    usable = np.flatnonzero(ok.sum(1) >= MIN_PAIR_JOINTS)
    if len(usable) < MIN_PAIRINGS:
        return None
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
        E, _ = cv2.findEssentialMat(pa, pb, np.eye(3), cv2.RANSAC, 0.999, threshold, HYPOTHESIS_ITERATIONS)
        for candidate in _split(E):
            count, accepted, inlier = _score(candidate, xa, xb, ok, threshold)
            if count > best[0]:
                best = (count, candidate, accepted, inlier)
    if best[1] is None or best[2].sum() < MIN_PAIRINGS:
        return None
    _, E, accepted, inlier = best
    refit, _ = cv2.findEssentialMat(xa[inlier], xb[inlier], np.eye(3), cv2.RANSAC, 0.999, threshold)
    for candidate in _split(refit):
        count, acc, inl = _score(candidate, xa, xb, ok, threshold)
        if count >= best[0]:
            best = (count, candidate, acc, inl)
    return best[1], best[2], best[3]


def relative_pose(xa: np.ndarray, xb: np.ndarray, ok: np.ndarray, threshold: float, rng: np.random.Generator
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """``(R, t, accepted (M,), joint inliers (M, 17))`` with ``x_b = R x_a + t`` (``|t| = 1``)
    from candidate pairings (:func:`essential_from_pairings`), or None."""
    found = essential_from_pairings(xa, xb, ok, threshold, rng)
    if found is None:
        return None
    E, accepted, inlier = found
    _, R, t, _ = cv2.recoverPose(E, xa[inlier].reshape(-1, 1, 2), xb[inlier].reshape(-1, 1, 2), np.eye(3))
    return R, t.ravel(), accepted, inlier


def pair_poses(x: np.ndarray, present: np.ndarray, camera: np.ndarray, instant: np.ndarray, focal: np.ndarray,
               rng: np.random.Generator) -> dict[tuple[int, int], PairPose]:
    """The relative pose of every camera pair that shares enough people (step 1).

    Args:
        x: ``(N, 17, 2)`` normalized joints; present: ``(N, 17)``; camera, instant: ``(N,)``.
        focal: ``(V,)`` focal lengths (px), for the pixel threshold.
    """
    out = {}
    V = len(focal)
    for a in range(V):
        for b in range(a + 1, V):
            rows_a, rows_b = np.flatnonzero(camera == a), np.flatnonzero(camera == b)
            ia, jb = aligned_pairs(instant[rows_a], instant[rows_b])
            ia, jb = rows_a[ia], rows_b[jb]
            ok = present[ia] & present[jb]
            threshold = INLIER_PX / np.sqrt(focal[a] * focal[b])
            found = relative_pose(x[ia], x[jb], ok, threshold, rng)
            if found is None:
                continue
            R, t, accepted, inlier = found
            E = _essential(R, t)
            error = float(np.median(sampson(E, x[ia][inlier], x[jb][inlier]))) * np.sqrt(focal[a] * focal[b])
            out[a, b] = PairPose(a, b, R, t, ia[accepted], jb[accepted], error)
    return out


def _essential(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return tx @ R


def person_components(pairs: dict[tuple[int, int], PairPose], n_poses: int, camera: np.ndarray) -> np.ndarray:
    """Persons: the 2D poses linked by accepted pairings (connected components). A component
    holding two poses of one camera keeps only its first pose of that camera.
    ``-> (N,)`` person index (-1: linked to no other pose)."""
    parent = np.arange(n_poses)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for pair in pairs.values():
        for i, j in zip(pair.pose_a, pair.pose_b):
            ri, rj = find(i), find(j)
            if ri != rj:
                parent[max(ri, rj)] = min(ri, rj)
    root = np.array([find(i) for i in range(n_poses)])
    _, person, counts = np.unique(root, return_inverse=True, return_counts=True)
    person = np.where(counts[person] >= 2, person, -1)
    key = np.where(person >= 0, person * (camera.max() + 1) + camera, -1)
    _, first = np.unique(key, return_index=True)
    keep = np.zeros(n_poses, bool)
    keep[first] = True
    person = np.where(keep, person, -1)
    _, person_compact = np.unique(person, return_inverse=True)
    return np.where(person >= 0, person_compact - (person.min() < 0), -1)


def spanning_tree(pairs: dict[tuple[int, int], PairPose], n_cameras: int) -> list[tuple[int, int]]:
    """Maximum spanning tree of the pairs (weight: accepted pairings) grown from camera 0:
    ``[(parent, child)]`` in placing order. A camera it cannot reach raises :class:`CalibrationError`."""
    placed, tree = {0}, []
    while len(placed) < n_cameras:
        edges = [(len(p.pose_a), a, b) for (a, b), p in pairs.items() if (a in placed) != (b in placed)]
        if not edges:
            missing = min(set(range(n_cameras)) - placed)
            raise CalibrationError(missing, "shares no people with the other cameras")
        _, a, b = max(edges)
        parent, child = (a, b) if a in placed else (b, a)
        tree.append((parent, child))
        placed.add(child)
    return tree


def triangulate_people(x: np.ndarray, present: np.ndarray, camera: np.ndarray, person: np.ndarray,
                       R: np.ndarray, t: np.ndarray, placed: np.ndarray) -> np.ndarray:
    """Every person's joints from its poses in the ``placed: (V,)`` cameras (normalized DLT).
    ``-> (Q, 17, 3)`` (NaN with fewer than two views)."""
    Q = person.max() + 1
    V = len(R)
    rows = np.flatnonzero((person >= 0) & placed[camera])
    obs = np.zeros((Q, V, NUM_JOINTS, 2))
    w = np.zeros((Q, V, NUM_JOINTS))
    obs[person[rows], camera[rows]] = x[rows]
    w[person[rows], camera[rows]] = present[rows]
    P = np.concatenate([R, t[:, :, None]], 2)                                     # (V, 3, 4)
    pts = np.moveaxis(obs, 2, 1)                                                  # (Q, 17, V, 2)
    return triangulate_dlt(pts, np.broadcast_to(P, (Q, NUM_JOINTS, V, 3, 4)), np.moveaxis(w, 2, 1))


def _place(parent: int, child: int, pair: PairPose, R: np.ndarray, t: np.ndarray, X: np.ndarray,
           x: np.ndarray, present: np.ndarray, camera: np.ndarray, person: np.ndarray) -> None:
    """Place ``child`` from ``parent`` along ``pair`` (module docstring, step 2), in place."""
    if pair.a == parent:
        R_pc, t_pc = pair.R, pair.t
    else:                                                                         # invert b -> a
        R_pc, t_pc = pair.R.T, -pair.R.T @ pair.t
    R[child] = R_pc @ R[parent]
    base = R_pc @ t[parent]
    rows = np.flatnonzero((camera == child) & (person >= 0))
    Xc = X[person[rows]]                                                          # (n, 17, 3)
    use = present[rows] & np.isfinite(Xc).all(-1)
    xh = np.concatenate([x[rows], np.ones(x[rows].shape[:-1] + (1,))], -1)[use]  # (m, 3)
    Y = Xc[use] @ R[child].T + base
    a = np.cross(xh, t_pc)
    b = np.cross(xh, Y)
    denominator = (a * a).sum(-1)
    s = -(a * b).sum(-1) / np.maximum(denominator, 1e-12)
    if len(s) < 10:
        raise CalibrationError(child, f"too few joints shared with camera {parent} to place it")
    t[child] = base + np.median(s) * t_pc


def world_from_people(X: np.ndarray, R0_right: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The similarity to the people's world (module docstring, step 4): ``X_world = s W X + b``.

    Args:
        X: ``(Q, 17, 3)`` the people's joints in the adjustment's frame.
        R0_right: ``(3,)`` the reference camera's right axis in that frame.
    Returns:
        ``(s, W (3, 3), b (3,))``.
    """
    lengths = bone_lengths(X)                                                     # (Q, 12)
    median = np.nanmedian(lengths, axis=0)
    known = np.isfinite(median)
    if not known.any():
        raise CalibrationError(None, "no bone of the people could be measured")
    s = float(MEAN_BONE_LENGTHS_M[known].sum() / median[known].sum())
    hip, knee, ankle = X[:, _HIPS], X[:, _KNEES], X[:, _ANKLES]
    leg = np.linalg.norm(hip - knee, axis=-1) + np.linalg.norm(knee - ankle, axis=-1)
    straight = (np.linalg.norm(hip - ankle, axis=-1) >= STRAIGHT_LEG * leg).all(-1)
    axis = X[:, _SHOULDERS].mean(1) - X[:, _ANKLES].mean(1)                        # (Q, 3)
    axis = axis[straight & np.isfinite(axis).all(-1)]
    if not len(axis):
        axis = (X[:, _SHOULDERS].mean(1) - X[:, _ANKLES].mean(1))
        axis = axis[np.isfinite(axis).all(-1)]
    if not len(axis):
        raise CalibrationError(None, "no body is seen whole: the vertical is unknown")
    up = (axis / np.linalg.norm(axis, axis=-1, keepdims=True)).mean(0)
    up /= np.linalg.norm(up)
    ankles = X[:, _ANKLES]                                                        # the standing foot: the lower ankle
    lower = np.take_along_axis(ankles, np.nanargmin(np.where(np.isfinite(ankles @ up), ankles @ up, np.inf),
                                                    axis=1)[:, None, None], 1)[:, 0]
    lower = lower[np.isfinite(lower).all(-1)]
    if len(lower) >= 3:                       # people walking about: the floor through their feet is finer
        _, spread, vt = np.linalg.svd(lower - lower.mean(0), full_matrices=False)
        if s * spread[1] / np.sqrt(len(lower)) >= FLOOR_MIN_SPREAD_M:
            up = vt[2] * np.sign(vt[2] @ up)
    x_axis = R0_right - (R0_right @ up) * up
    x_axis /= np.linalg.norm(x_axis)
    W = np.stack([x_axis, np.cross(up, x_axis), up])                              # rows: world x, y, z
    feet = np.einsum("ij,qkj->qki", W, X[:, _ANKLES]) * s                         # (Q, 2, 3)
    lowest = np.min(np.where(np.isfinite(feet[..., 2]), feet[..., 2], np.inf), axis=1)
    floor = float(np.median(lowest[np.isfinite(lowest)]))
    centre = np.nanmean(feet.reshape(-1, 3)[:, :2], axis=0)
    b = -np.array([centre[0], centre[1], floor])
    return s, W, b


def calibrate_from_people(keypoints: np.ndarray, camera: np.ndarray, instant: np.ndarray, K: np.ndarray,
                          seed: int = 0, refine_focal: bool = False) -> PeopleCalibration:
    """Every camera's rotation and position from the people's 2D poses (module docstring).

    Args:
        keypoints: ``(N, 17, 3)`` undistorted 2D poses (pixels, confidence; 0: missing) of
            synchronized cameras; camera: ``(N,)`` in ``0 .. V-1``; instant: ``(N,)``.
        K: ``(V, 3, 3)`` intrinsics.
        refine_focal: adjust every camera's focal length in the bundle adjustment too (its
            principal point and aspect ratio stay).
    Returns:
        :class:`PeopleCalibration` in the people's world (metres). Raises
        :class:`CalibrationError` naming the camera that cannot be placed or does not converge.
    """
    V = len(K)
    if V < 2:
        raise CalibrationError(None, "one camera: at least two are needed")
    for c in range(V):
        if not (camera == c).any():
            raise CalibrationError(c, "no 2D poses")
    instants = np.unique(instant)
    if len(instants) > MAX_INSTANTS:
        keep_instants = instants[np.linspace(0, len(instants) - 1, MAX_INSTANTS).round().astype(int)]
        keep = np.isin(instant, keep_instants)
        keypoints, camera, instant = keypoints[keep], camera[keep], instant[keep]
    rng = np.random.default_rng(seed)
    focal = 0.5 * (K[:, 0, 0] + K[:, 1, 1])
    x = normalized_points(keypoints, K[camera])
    present = keypoints[..., 2] > 0
    pairs = pair_poses(x, present, camera, instant, focal, rng)
    tree = spanning_tree(pairs, V)
    person = person_components(pairs, len(x), camera)
    if person.max() < 0:
        raise CalibrationError(None, "no person is seen by two cameras")
    R = np.repeat(np.eye(3)[None], V, 0)
    t = np.zeros((V, 3))
    placed = np.zeros(V, bool)
    placed[0] = True
    for parent, child in tree:
        pair = pairs[min(parent, child), max(parent, child)]
        if placed.sum() == 1:
            R[child] = pair.R if pair.a == parent else pair.R.T
            t[child] = pair.t if pair.a == parent else -pair.R.T @ pair.t
        else:
            X = triangulate_people(x, present, camera, person, R, t, placed)
            _place(parent, child, pair, R, t, X, x, present, camera, person)
        placed[child] = True
    X = triangulate_people(x, present, camera, person, R, t, placed)
    R, t, X, refined, converged = bundle_adjust(x, present, camera, person, focal, R, t, X, refine_focal)
    error = reprojection_px(x, present, camera, person, focal, R, t, X, refined if refine_focal else None)
    residual = np.array([np.nanmedian(error[camera == c]) if np.isfinite(error[camera == c]).any() else np.inf
                         for c in range(V)])
    observations = np.array([int(np.isfinite(error[camera == c]).sum()) for c in range(V)])
    worst = int(np.argmax(residual))
    if residual[worst] > MAX_RESIDUAL_PX:
        raise CalibrationError(worst, f"the calibration does not converge (median reprojection error "
                                      f"{residual[worst]:.1f} px)")
    s, W, b = world_from_people(X, R[0][0])
    R_world = R @ W.T
    t_world = s * t - np.einsum("vij,j->vi", R_world, b)
    X_world = s * X @ W.T + b
    instant_of = np.full(len(X), -1)
    instant_of[person[person >= 0]] = instant[person >= 0]
    return PeopleCalibration(R_world, t_world, residual, observations, tree, X_world, instant_of, s, converged,
                             refined / focal)
