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

from dataclasses import dataclass, replace

import numpy as np

from mvm.core.camera import normalized_points
from mvm.core.geometry import triangulate_dlt
from mvm.core.keypoints import INDEX, MEAN_BONE_LENGTHS_M, NUM_JOINTS, bone_lengths
from mvm.core.scene import Cameras
from mvm.rig.bundle_adjustment import bundle_adjust, reprojection_px
from mvm.rig.people_pairs import MIN_PAIRINGS, PairCount, PairPose, pair_poses

#: Instants used at most (evenly spread) for the pairs and the bundle adjustment.
MAX_INSTANTS = 150
#: The calibration has not converged when a camera's median reprojection error exceeds this. [px]
MAX_RESIDUAL_PX = 15.0
#: The floor is fitted through the people's feet (its normal the vertical) when they spread
#: this much (standard deviation) along its narrower direction; else the bodies' axis. [m]
FLOOR_MIN_SPREAD_M = 0.15
#: Straight legs: hip-to-ankle distance at least this fraction of thigh + shank. [1]
STRAIGHT_LEG = 0.9

#: The confidence each joint needs to be used: any for the body's (shoulders to ankles); the
#: face's only where the detector is confident of them. A face point is on the skin, and a
#: camera behind the person does not see it: the detector guesses it, tens of pixels off on real
#: footage (YOLO11n-pose: 35-90 px), at a lower confidence. On the real 4-camera capture the
#: centres land 64 mm (mean) from the lab's with the confident face points, 68 without any and
#: 91 with all; on the Panoptic dome (5 cameras) 1.7, 7.7 and 1.7 mm. [0-1]
MIN_JOINT_CONFIDENCE = np.where(np.arange(NUM_JOINTS) < INDEX["left_shoulder"], 0.5, 0.0)
#: A camera is placed only when the median angle between its rays and the other cameras' rays to
#: the same joints is at least this (smaller: the baseline is too short to measure depth). [deg]
MIN_PARALLAX_DEG = 2.0

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
class PeopleCalibration:
    """Extrinsics found from the people.

    Attributes:
        cameras: the :class:`~mvm.core.scene.Cameras` given, with their rotations ``R (V, 3, 3)``
            and translations ``t (V, 3)`` (metres) found, world -> camera, and their focal
            lengths refined when asked (``focal_scale``).
        residual_px: ``(V,)`` median reprojection error of each camera's joints after adjustment.
        observations: ``(V,)`` joints of each camera in the adjustment.
        tree: ``[(parent, child)]`` the spanning tree the cameras were placed along.
        points: ``(Q, 17, 3)`` the people's joints (world, metres; NaN: not triangulated);
        point_instant: ``(Q,)`` their instants.
        scale_m: metres per unit of the adjustment; converged: the solver met its tolerance (not
            its evaluation limit).
        focal_scale: ``(V,)`` each camera's focal length over the one given (1 unless refined).
        position_sd_m: ``(V,)`` each camera centre's standard deviation relative to the
            reference camera (metres; 0 for it), from the bundle adjustment's Jacobian.
    """

    cameras: Cameras
    residual_px: np.ndarray
    observations: np.ndarray
    tree: list
    points: np.ndarray
    point_instant: np.ndarray
    scale_m: float
    converged: bool
    focal_scale: np.ndarray
    position_sd_m: np.ndarray


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


def calibrate_from_people(keypoints: np.ndarray, camera: np.ndarray, instant: np.ndarray, cameras: Cameras,
                          seed: int = 0, refine_focal: bool = False) -> PeopleCalibration:
    """Every camera's rotation and position from the people's 2D poses (module docstring).

    Args:
        keypoints: ``(N, 17, 3)`` 2D poses (pixels, confidence; 0: missing) of synchronized
            cameras, undistorted already (as a rig's reader gives them: its lens is not undone
            again); camera: ``(N,)`` in ``0 .. V-1``; instant: ``(N,)``.
        cameras: the ``V`` cameras' intrinsics (``K``, size, names and the lens the keypoints
            were seen through; their ``R``, ``t`` are ignored).
        refine_focal: adjust every camera's focal length in the bundle adjustment too (its
            principal point and aspect ratio stay).
    Returns:
        :class:`PeopleCalibration` in the people's world (metres). Raises
        :class:`CalibrationError` naming the camera that cannot be placed or does not converge.
    """
    K, V = cameras.K, len(cameras)
    if V < 2:
        raise CalibrationError(None, "one camera: at least two are needed")
    for c in range(V):
        if not (camera == c).any():
            raise CalibrationError(c, "no 2D poses")
    keypoints, camera, instant = _spread_instants(keypoints, camera, instant)
    rng = np.random.default_rng(seed)
    focal = cameras.focal
    x = normalized_points(keypoints, K[camera])
    present = (keypoints[..., 2] > 0) & (keypoints[..., 2] >= MIN_JOINT_CONFIDENCE)
    pairs, counts = pair_poses(keypoints, x, present, camera, instant, focal, rng)
    try:
        tree = spanning_tree(pairs, V)
    except CalibrationError as e:
        raise CalibrationError(e.camera, _unplaced(e.camera, counts)) from None
    person = person_components(pairs, len(x), camera)
    if person.max() < 0:
        raise CalibrationError(None, "no person is seen by two cameras")
    R, t = _place_along(tree, pairs, V, x, present, camera, person)
    X = triangulate_people(x, present, camera, person, R, t, np.ones(V, bool))
    pinhole = replace(cameras, R=R, t=t, distortion=(), fisheye=None)              # the lens is undone already
    adjusted = bundle_adjust(pinhole, keypoints[..., :2], present, camera, person, X, refine_focal,
                             weight=keypoints[..., 2])
    R, t, X = adjusted.cameras.R, adjusted.cameras.t, adjusted.X
    error = reprojection_px(adjusted.cameras, keypoints[..., :2], present, camera, person, X)
    parallax = parallax_deg(x, np.isfinite(error), camera, person, R, t, X)
    residual, observations = _checked_fit(error, camera, V, parallax)
    s, W, b = world_from_people(X, R[0][0])
    R_world = R @ W.T
    t_world = s * t - np.einsum("vij,j->vi", R_world, b)
    X_world = s * X @ W.T + b
    instant_of = np.full(len(X), -1)
    instant_of[person[person >= 0]] = instant[person >= 0]
    found = replace(cameras, K=adjusted.cameras.K, R=R_world, t=t_world)
    return PeopleCalibration(found, residual, observations, tree, X_world, instant_of, s,
                             adjusted.converged, adjusted.focal_scale, s * adjusted.centre_sd)


def _spread_instants(keypoints: np.ndarray, camera: np.ndarray, instant: np.ndarray) -> tuple:
    """The 2D poses ``(N, 17, 3)``, their cameras and instants ``(N,)`` of at most
    :data:`MAX_INSTANTS` instants, evenly spread."""
    instants = np.unique(instant)
    if len(instants) <= MAX_INSTANTS:
        return keypoints, camera, instant
    keep = np.isin(instant, instants[np.linspace(0, len(instants) - 1, MAX_INSTANTS).round().astype(int)])
    return keypoints[keep], camera[keep], instant[keep]


def _place_along(tree: list, pairs: dict, V: int, x: np.ndarray, present: np.ndarray, camera: np.ndarray,
                 person: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R (V, 3, 3), t (V, 3))``: the cameras placed along the spanning ``tree`` from camera 0,
    the first child by its pair's relative pose, each next one against the people triangulated by
    those placed before it (:func:`_place`)."""
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
    return R, t


def _checked_fit(error: np.ndarray, camera: np.ndarray, V: int, parallax: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(residual_px (V,), observations (V,))`` of the adjusted cameras, from the reprojection
    ``error: (N, 17)`` of each pose's joints (NaN: not adjusted) and each camera's median
    ``parallax: (V,)``; a camera whose median error exceeds :data:`MAX_RESIDUAL_PX`, or whose rays
    meet the others' under :data:`MIN_PARALLAX_DEG`, raises :class:`CalibrationError`."""
    residual = np.array([np.nanmedian(error[camera == c]) if np.isfinite(error[camera == c]).any() else np.inf
                         for c in range(V)])
    observations = np.array([int(np.isfinite(error[camera == c]).sum()) for c in range(V)])
    worst = int(np.argmax(residual))
    if residual[worst] > MAX_RESIDUAL_PX:
        raise CalibrationError(worst, f"the calibration does not converge (median reprojection error "
                                      f"{residual[worst]:.1f} px)")
    short = int(np.nanargmin(np.where(np.isfinite(parallax), parallax, -1.0)))
    if not parallax[short] >= MIN_PARALLAX_DEG:
        raise CalibrationError(short, f"its rays meet the other cameras' at {parallax[short]:.1f}° (median), under "
                                      f"{MIN_PARALLAX_DEG:g}°: too short a baseline to place it")
    return residual, observations


def _unplaced(camera: int, counts: dict[tuple[int, int], PairCount]) -> str:
    """Why ``camera`` could not be placed, from the pairings it has with the other cameras."""
    mine = [c for pair, c in counts.items() if camera in pair]
    candidates = sum(c.candidates for c in mine)
    distinct = max((c.distinct for c in mine), default=0)
    if not candidates:
        return "shares no people with the other cameras"
    if distinct < MIN_PAIRINGS:
        return (f"shares only people standing still with the other cameras ({distinct} distinct poses "
                f"among {candidates} pairings, {MIN_PAIRINGS} needed): film someone moving through its view")
    return (f"the people it shares with the other cameras ({distinct} distinct poses at most with one camera) "
            "give no consistent relative pose")


def parallax_deg(x: np.ndarray, used: np.ndarray, camera: np.ndarray, person: np.ndarray, R: np.ndarray,
                 t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Each camera's median angle between its ray to a joint and the farthest other camera's ray
    to it. ``x: (N, 17, 2)``, ``used: (N, 17)`` the observations adjusted, ``camera, person: (N,)``,
    ``R, t``: ``(V, 3, 3)``, ``(V, 3)``, ``X: (Q, 17, 3)`` -> ``(V,)`` degrees (NaN: no joint)."""
    V, Q = len(R), len(X)
    centres = -np.einsum("vji,vj->vi", R, t)
    rays = X[:, :, None] - centres[None, None]                                    # (Q, 17, V, 3)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    seen = np.zeros((Q, NUM_JOINTS, V), bool)
    rows = np.flatnonzero(person >= 0)
    seen[person[rows], :, camera[rows]] = used[rows]
    cosine = np.einsum("qjvk,qjwk->qjvw", rays, rays)
    cosine = np.where(seen[..., None, :] & ~np.eye(V, dtype=bool), cosine, np.inf).min(-1)       # (Q, 17, V)
    angle = np.degrees(np.arccos(np.clip(np.where(np.isfinite(cosine), cosine, np.nan), -1, 1)))
    return np.array([np.nanmedian(angle[..., v][seen[..., v]]) if (seen[..., v] & np.isfinite(angle[..., v])).any()
                     else np.nan for v in range(V)])
