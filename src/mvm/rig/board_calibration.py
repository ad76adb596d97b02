"""Calibrating a rig with a board (checkerboard or ChArUco) seen in its videos (no I/O), as
Pose2Sim and anipose do with OpenCV.

1. **Intrinsics**, each camera alone: ``cv2.calibrateCamera`` on views of the board spread over
   the image, its distance and its tilts (:func:`mvm.rig.boards.spread_views`), OpenCV's
   ``k1, k2, p1, p2`` lens (or ``cv2.fisheye.calibrate``, its ``k1 .. k4``).
2. **Board poses**: ``cv2.solvePnP`` (IPPE, for a plane) of every view, on the corners
   undistorted by the camera's lens.
3. **Chaining.** Two cameras that see the board at the same instant give their relative pose
   (``R_b R_a^T``, ``t_b - R_b R_a^T t_a``); over the instants they share, its robust mean (the
   chordal mean of the rotations, the median translation). Cameras are placed along a maximum
   spanning tree of the pairs (weighted by shared views) from the reference camera 0, in metres.
4. **Bundle adjustment** over every camera but the reference and every corner of every shared
   view (:func:`mvm.rig.bundle_adjustment.bundle_adjust`, the one of the calibration from people).
5. **World frame.** ``"board"``: the board of one view (the first one seen by the most cameras):
   the origin on its first corner, x along its first row of corners, z out of its face towards
   the cameras that see it (up when it lies on the floor), metres from the board's squares
   (the median scale over every view). ``"camera"``: the reference camera's frame (x right, y
   down, z forward), in metres.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from mvm.core.camera import undistort_views
from mvm.core.geometry import similarity_transform
from mvm.core.scene import Cameras
from mvm.rig.boards import MIN_CORNERS, spread_views, view_features
from mvm.rig.bundle_adjustment import bundle_adjust, reprojection_px
from mvm.rig.calibrate import CalibrationError, spanning_tree
from mvm.rig.people_pairs import PairPose

#: The cells an image is cut into to measure how much of it the board's views cover. [cols, rows]
COVERAGE_GRID = (8, 6)
#: Below this share of the image covered, the lens is poorly told (said as a warning). [1]
MIN_COVERAGE = 0.5
#: Views of the board each camera's intrinsics are calibrated on, at most (spread apart).
MAX_INTRINSIC_VIEWS = 40
#: Fewest views of the board for a camera's intrinsics.
MIN_INTRINSIC_VIEWS = 5
#: A view spans the board's plane when its corners' spread across their main direction is at
#: least this fraction of the spread along it. [1]
MIN_SPAN = 0.1
#: Instants seen by two cameras or more that the bundle adjustment uses, at most (spread apart).
MAX_SHARED_VIEWS = 60
#: A pair's view is an outlier when its relative rotation is this far from the pair's median. [deg]
OUTLIER_ROTATION_DEG = 5.0
#: A view is left out (and the rest calibrated again) when its reprojection RMS exceeds this and
#: three times the median view's (a board found shifted by a square, a blurred frame). [px]
OUTLIER_VIEW_PX = 1.0
#: The intrinsics or the rig have not converged when a camera's reprojection RMS exceeds this. [px]
MAX_RMS_PX = 3.0

#: What to check when the cameras' views of the board do not agree.
SYNC_HINT = "are the extrinsics videos recorded together, and the intrinsics right?"


@dataclass
class Intrinsics:
    """One camera's intrinsics: ``K (3, 3)``, ``distortion (4,)`` (OpenCV ``k1, k2, p1, p2``, or
    the fisheye model's ``k1 .. k4``),
    ``rms_px`` (reprojection RMS over the views used), ``views`` (indices of those views),
    ``coverage`` (:func:`image_coverage` of those views)."""

    K: np.ndarray
    distortion: np.ndarray
    rms_px: float
    views: np.ndarray
    coverage: float


def image_coverage(corners: np.ndarray, size: tuple[int, int]) -> float:
    """The share of the image's cells (``COVERAGE_GRID``) holding a corner of ``corners: (F, C, 2)``
    (pixels, NaN: not seen): a lens is told by views that reach the image's edges."""
    cols, rows = COVERAGE_GRID
    px = corners[np.isfinite(corners).all(-1)]
    cell = np.floor(px / np.asarray(size, float) * [cols, rows]).astype(int)
    inside = (cell >= 0).all(1) & (cell < [cols, rows]).all(1)
    return len(np.unique(cell[inside, 1] * cols + cell[inside, 0])) / (cols * rows)


@dataclass
class BoardRig:
    """Extrinsics found from a board.

    Attributes:
        cameras: the :class:`~mvm.core.scene.Cameras` given, with their rotations ``R (V, 3, 3)``
            and translations ``t (V, 3)`` (metres) found, world -> camera.
        rms_px: ``(V,)`` each camera's reprojection RMS after the adjustment.
        views: ``(V,)`` shared views of each camera in the adjustment.
        tree: ``[(parent, child)]`` the spanning tree the cameras were placed along.
        world_view: the instant (index into the common instants) whose board is the world frame
            (-1: the reference camera's frame).
        converged: the solver met its tolerance (not its evaluation limit).
    """

    cameras: Cameras
    rms_px: np.ndarray
    views: np.ndarray
    tree: list
    world_view: int
    converged: bool


def usable_views(corners: np.ndarray, object_points: np.ndarray) -> np.ndarray:
    """``(F,)`` the views of ``corners: (F, C, 2)`` with at least ``MIN_CORNERS`` corners that
    span the board's plane (not all along one line of a ChArUco board seen in part)."""
    seen = np.isfinite(corners).all(-1)                                           # (F, C)
    n = seen.sum(1)
    xy = np.where(seen[..., None], object_points[None, :, :2], 0.0)
    mean = xy.sum(1) / np.maximum(n, 1)[:, None]
    d = np.where(seen[..., None], xy - mean[:, None], 0.0)
    spread = np.linalg.eigvalsh(np.einsum("fci,fcj->fij", d, d))                  # (F, 2), ascending
    return (n >= MIN_CORNERS) & (spread[:, 0] > MIN_SPAN ** 2 * np.maximum(spread[:, 1], 1e-12))


def _views(corners: np.ndarray, object_points: np.ndarray, index: np.ndarray) -> tuple[list, list]:
    """OpenCV's lists of object and image points of the views ``index`` of ``corners: (F, C, 2)``."""
    seen = np.isfinite(corners[index]).all(-1)
    obj = [object_points[s].astype(np.float32) for s in seen]
    img = [c[s].astype(np.float32).reshape(-1, 1, 2) for c, s in zip(corners[index], seen)]
    return obj, img


#: Where OpenCV keeps the fisheye calibration's flags (``cv2.fisheye`` up to 4.x, ``cv2`` from 5).
_FISHEYE = cv2.fisheye if hasattr(cv2.fisheye, "CALIB_RECOMPUTE_EXTRINSIC") else cv2


def _calibrate_lens(obj: list, img: list, size: tuple[int, int], fisheye: bool
                    ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """One OpenCV calibration: ``(rms, K, distortion, per-view RMS)``."""
    if not fisheye:
        rms, K, dist, _, _, _, _, per_view = cv2.calibrateCameraExtended(obj, img, size, None, None,
                                                                         flags=cv2.CALIB_FIX_K3)
        return rms, K, dist.reshape(-1)[:4].copy(), per_view.ravel()
    obj = [o.reshape(1, -1, 3).astype(np.float64) for o in obj]                  # the shapes it accepts
    img = [i.reshape(1, -1, 2).astype(np.float64) for i in img]
    rms, K, dist, rvecs, tvecs = cv2.fisheye.calibrate(
        obj, img, size, None, None, flags=_FISHEYE.CALIB_RECOMPUTE_EXTRINSIC | _FISHEYE.CALIB_FIX_SKEW,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-9))
    per_view = np.array([np.sqrt(np.mean(np.sum((cv2.fisheye.projectPoints(o, r, t, K, dist)[0] - i) ** 2, -1)))
                         for o, i, r, t in zip(obj, img, rvecs, tvecs)])
    return rms, K, dist.reshape(-1).copy(), per_view


def calibrate_intrinsics(corners: np.ndarray, object_points: np.ndarray, size: tuple[int, int],
                         max_views: int = MAX_INTRINSIC_VIEWS, fisheye: bool = False) -> Intrinsics:
    """One camera's intrinsics from its views of the board (module docstring, step 1).

    Args:
        corners: ``(F, C, 2)`` the board's corners in ``F`` views (pixels, NaN: not seen).
        object_points: ``(C, 3)`` the corners on the board (metres); size: ``(width, height)``.
        fisheye: OpenCV's fisheye lens (``cv2.fisheye.calibrate``, ``k1 .. k4``).
    Raises:
        CalibrationError (camera None) with too few views or a RMS above ``MAX_RMS_PX``.
    """
    usable = np.flatnonzero(usable_views(corners, object_points))
    if len(usable) < MIN_INTRINSIC_VIEWS:
        raise CalibrationError(None, f"the board is seen in {len(usable)} frame(s), at least "
                                     f"{MIN_INTRINSIC_VIEWS} are needed for the intrinsics")
    features = np.array([view_features(corners[f][np.isfinite(corners[f]).all(-1)], size) for f in usable])
    chosen = usable[spread_views(features, max_views)]
    for _ in range(2):                                    # once more without the views it does not explain
        try:
            rms, K, dist, per_view = _calibrate_lens(*_views(corners, object_points, chosen),
                                                     tuple(int(v) for v in size), fisheye)
        except cv2.error:
            rms = np.inf
            break
        good = per_view <= max(OUTLIER_VIEW_PX, 3 * np.median(per_view))
        if good.all() or good.sum() < MIN_INTRINSIC_VIEWS:
            break
        chosen = chosen[good]
    if not np.isfinite(rms) or rms > MAX_RMS_PX:
        raise CalibrationError(None, f"the intrinsics do not converge (reprojection RMS {rms:.2f} px over "
                                     f"{len(chosen)} views)")
    return Intrinsics(K, dist, float(rms), chosen, image_coverage(corners[chosen], size))


def board_poses(corners: np.ndarray, K: np.ndarray, object_points: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                        np.ndarray]:
    """The board's pose in every view (step 2): ``corners: (F, C, 2)`` undistorted pixels ->
    ``R (F, 3, 3)``, ``t (F, 3)`` (board -> camera, metres; NaN where unseen), ``ok (F,)``."""
    F = len(corners)
    R, t = np.full((F, 3, 3), np.nan), np.full((F, 3), np.nan)
    seen = np.isfinite(corners).all(-1)
    for f in np.flatnonzero(usable_views(corners, object_points)):
        ok, rvec, tvec = cv2.solvePnP(object_points[seen[f]], corners[f][seen[f]], K, None,
                                      flags=cv2.SOLVEPNP_IPPE)
        if ok and tvec[2, 0] > 0:
            R[f], t[f] = cv2.Rodrigues(rvec)[0], tvec.ravel()
    return R, t, np.isfinite(t).all(-1)


def _chordal_mean(R: np.ndarray) -> np.ndarray:
    """The rotation nearest the mean of ``R: (n, 3, 3)``."""
    U, _, Vt = np.linalg.svd(R.mean(0))
    return U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def pair_pose(Ra: np.ndarray, ta: np.ndarray, Rb: np.ndarray, tb: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                      np.ndarray]:
    """The relative pose ``x_b = R x_a + t`` of two cameras from the board's poses at the instants
    both see it (step 3): ``Ra, Rb: (n, 3, 3)``, ``ta, tb: (n, 3)`` -> ``(R, t, kept (n,))``, the
    instants whose rotation agrees with the others'."""
    R = Rb @ np.swapaxes(Ra, 1, 2)                                               # (n, 3, 3)
    t = tb - np.einsum("nij,nj->ni", R, ta)
    mean = _chordal_mean(R)
    angle = np.degrees(np.arccos(np.clip((np.einsum("nij,ij->n", R, mean) - 1) / 2, -1, 1)))
    keep = angle <= max(OUTLIER_ROTATION_DEG, np.median(angle) * 3)
    return _chordal_mean(R[keep]), np.median(t[keep], axis=0), keep


def _place_cameras(R_board: np.ndarray, t_board: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray, list]:
    """Every camera's pose in the reference camera's frame (step 3). ``R_board: (V, T, 3, 3)``,
    ``t_board: (V, T, 3)``, ``ok: (V, T)`` -> ``R (V, 3, 3)``, ``t (V, 3)``, the tree."""
    V = len(ok)
    pairs = {}
    for a in range(V):
        for b in range(a + 1, V):
            both = np.flatnonzero(ok[a] & ok[b])
            if len(both):
                R, t, kept = pair_pose(R_board[a, both], t_board[a, both], R_board[b, both], t_board[b, both])
                pairs[a, b] = PairPose(a, b, R, t, both[kept], both[kept], 0.0)   # weighted by shared views
    try:
        tree = spanning_tree(pairs, V)
    except CalibrationError as e:
        raise CalibrationError(e.camera, "never sees the board at the same instant as the other cameras") from None
    R, t = np.repeat(np.eye(3)[None], V, 0), np.zeros((V, 3))
    for parent, child in tree:
        pair = pairs[min(parent, child), max(parent, child)]
        R_pc, t_pc = (pair.R, pair.t) if pair.a == parent else (pair.R.T, -pair.R.T @ pair.t)
        R[child], t[child] = R_pc @ R[parent], R_pc @ t[parent] + t_pc
    return R, t, tree


def _corners_in_world(R_board, t_board, ok, R, t, object_points) -> np.ndarray:
    """Every instant's corners in the cameras' frame, the mean over the cameras that see the
    board: ``(T, C, 3)`` (NaN where none does)."""
    board = np.einsum("vtij,cj->vtci", R_board, object_points) + t_board[:, :, None]      # (V, T, C, 3)
    world = np.einsum("vji,vtcj->vtci", R, board - t[:, None, None])                      # R^T (x - t)
    world = np.where(ok[:, :, None, None], world, np.nan)
    with np.errstate(invalid="ignore"):
        return np.nanmean(world, axis=0)


def _world_frame(X: np.ndarray, seen: np.ndarray, object_points: np.ndarray, R: np.ndarray, t: np.ndarray,
                 world: str, view: int | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Cameras ``R (V, 3, 3)``, ``t (V, 3)`` of the adjustment moved to the world frame (step 5).
    ``X: (T, C, 3)`` the adjusted corners; ``seen: (V, T)``; ``view``: the instant whose board is
    the world (default: the first seen by the most cameras) -> ``(R, t, world view)``."""
    obj = np.broadcast_to(object_points, X.shape)
    s, Rb, tb = similarity_transform(obj, X)                                      # X ≈ s Rb P + tb
    counted = np.isfinite(X).all(-1).sum(1) >= MIN_CORNERS
    scale = float(np.median(s[counted]))
    if world == "camera":
        return R, t / scale, -1
    f = int(np.flatnonzero(counted)[np.argmax(seen[:, counted].sum(0))]) if view is None else view
    if not counted[f] or seen[:, f].sum() < 2:
        raise CalibrationError(None, f"the board of the world frame is seen well by {seen[:, f].sum()} camera(s), "
                                     "at least two are needed")
    for flip in (np.eye(3), np.diag([1.0, -1.0, -1.0])):                         # z towards the cameras
        R_w = R @ Rb[f] @ flip                                                   # x = s R (Rb flip W) + R tb + t
        t_w = (np.einsum("vij,j->vi", R, tb[f]) + t) / scale
        centres = -np.einsum("vji,vj->vi", R_w, t_w)
        if centres[seen[:, f], 2].mean() > 0:
            break
    return R_w, t_w, f


def calibrate_extrinsics(corners: np.ndarray, cameras: Cameras, object_points: np.ndarray, world: str = "board",
                         world_instant: int | None = None) -> BoardRig:
    """Every camera's rotation and position from views of the board at common instants
    (module docstring, steps 2-5).

    Args:
        corners: ``(V, T, C, 2)`` the board's corners (pixels through the cameras' lens, NaN:
            not seen) in every camera at ``T`` common instants (synchronized videos).
        cameras: the ``V`` cameras' intrinsics (``K``, size, names, lens; their ``R``, ``t`` are
            ignored); object_points: ``(C, 3)`` (metres); world: ``"board"`` or ``"camera"``;
        world_instant: the instant whose board is the world (default: the first seen by the most cameras).
    Raises:
        CalibrationError naming a camera that shares no view with the others, or does not converge.
    """
    V, T, C = corners.shape[:3]
    R_board, t_board, ok = np.full((V, T, 3, 3), np.nan), np.full((V, T, 3), np.nan), np.zeros((V, T), bool)
    pinhole = undistort_views(cameras, corners, np.arange(V))                     # (V, T, C, 2)
    for v in range(V):
        R_board[v], t_board[v], ok[v] = board_poses(pinhole[v], cameras.K[v], object_points)
        if not ok[v].any():
            raise CalibrationError(v, "the board is not found in any frame")
    shared = np.flatnonzero(ok.sum(0) >= 2)
    if len(shared) > MAX_SHARED_VIEWS:
        shared = shared[np.linspace(0, len(shared) - 1, MAX_SHARED_VIEWS).round().astype(int)]
    if world_instant is not None:
        if ok[:, world_instant].sum() < 2:
            raise CalibrationError(None, f"the board of the world frame is found in {ok[:, world_instant].sum()} "
                                         "camera(s), at least two are needed")
        shared = np.union1d(shared, [world_instant])
    R_board, t_board, ok, corners = R_board[:, shared], t_board[:, shared], ok[:, shared], corners[:, shared]
    R, t, tree = _place_cameras(R_board, t_board, ok)
    X = _corners_in_world(R_board, t_board, ok, R, t, object_points)
    camera, instant = np.nonzero(ok)
    pixels = corners[camera, instant]                                             # (N, C, 2) through the lens
    present = np.isfinite(pixels).all(-1)
    cameras = replace(cameras, R=R, t=t)
    for _ in range(2):                                    # once more without the views it does not explain
        adjusted = bundle_adjust(cameras, pixels, present, camera, instant, X)
        cameras, X, converged = adjusted.cameras, adjusted.X, adjusted.converged
        error = reprojection_px(cameras, pixels, present, camera, instant, X)
        counted = np.isfinite(error)
        view_rms = np.sqrt((np.where(counted, error, 0) ** 2).sum(1) / np.maximum(counted.sum(1), 1))    # (N,)
        bad = view_rms > max(OUTLIER_VIEW_PX, 3 * np.median(view_rms[counted.any(1)]))
        if not bad.any():
            break
        present[bad] = False
        ok[camera[bad], instant[bad]] = False
    error = np.where(present, error, np.nan)
    for v in range(V):
        if not np.isfinite(error[camera == v]).any():
            raise CalibrationError(v, f"its views of the board disagree with the other cameras' ({SYNC_HINT})")
    rms = np.array([np.sqrt(np.nanmean(error[camera == v] ** 2)) for v in range(V)])
    worst = int(np.argmax(rms))
    if not rms[worst] <= MAX_RMS_PX:
        raise CalibrationError(worst, f"the calibration does not converge (reprojection RMS {rms[worst]:.2f} px; "
                                      f"{SYNC_HINT})")
    view = None if world_instant is None else int(np.searchsorted(shared, world_instant))
    R, t, f = _world_frame(X, ok, object_points, cameras.R, cameras.t, world, view)
    return BoardRig(replace(cameras, R=R, t=t), rms, ok.sum(1), tree, int(shared[f]) if f >= 0 else -1, converged)
