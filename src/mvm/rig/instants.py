"""The core pipeline (affinity, greedy grouping, RANSAC triangulation, refinement) run on many
instants of a synchronized rig at once.

Every instant is a static scene whose views are the ``V`` cameras. Per-instant Python work is
kept to the grouping (Algorithm 1 on an instant's few poses); the rest is batched:

- the epipolar distances of all instants of a batch are one product of ``(T, V, n, J, 3)``
  keypoints with the rig's fundamental matrices (``n`` the most poses of one camera at one instant);
- the triangulation treats the persons of all instants as one set of groups;
- the refinement solves all persons of the batch in one sparse problem (they are independent).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable

import numpy as np
from threadpoolctl import threadpool_limits

from mvm.core.affinity import affinity
from mvm.core.config import Config
from mvm.core.geometry import fundamental_matrices
from mvm.core.matching import greedy_groups
from mvm.core.reconstruct import merge_duplicates
from mvm.core.refine import refine_poses
from mvm.core.scene import Cameras, Poses2D
from mvm.core.triangulate import gather_groups, ransac_triangulate
from mvm.errors import InputError
from mvm.eval.metrics import reprojection_errors

log = logging.getLogger(__name__)


@dataclass
class Detections:
    """2D poses of many instants of a rig.

    Attributes:
        keypoints: ``(N, 17, 3)`` undistorted pixels and confidence (0: missing).
        instant: ``(N,)`` instant index (0 .. T-1) of each pose.
        camera: ``(N,)`` camera index of each pose.
        score: ``(N,)`` pose confidence.
    """

    keypoints: np.ndarray
    instant: np.ndarray
    camera: np.ndarray
    score: np.ndarray

    def __post_init__(self):
        self.keypoints = np.asarray(self.keypoints, dtype=float).reshape(-1, 17, 3)
        N = len(self.keypoints)
        for name, dtype in (("instant", np.int64), ("camera", np.int64), ("score", float)):
            value = np.asarray(getattr(self, name), dtype=dtype).reshape(-1)
            if len(value) != N:
                raise ValueError(f"Detections.{name}: expected {N} entries, got {len(value)}")
            setattr(self, name, value)

    def __len__(self) -> int:
        return len(self.keypoints)

    def subset(self, index: np.ndarray) -> "Detections":
        return Detections(self.keypoints[index], self.instant[index], self.camera[index], self.score[index])


@dataclass
class InstantPersons:
    """``Q`` persons reconstructed over many instants (a flat list, ``instant`` says when).

    Attributes:
        X: ``(Q, 17, 3)`` world joints, NaN where not reconstructed.
        instant: ``(Q,)`` instant index of each person (sorted).
        scores: ``(Q, 17)`` mean confidence of the inlier keypoints.
        members: ``(Q, V)`` detection index used from each camera, -1 where none.
        inliers, valid: ``(Q, V, 17)`` keypoints used / available, per camera.
        errors: ``(Q, V, 17)`` reprojection error of each available keypoint, px (NaN elsewhere).
        reprojection_error_px: ``(Q,)`` mean error over the inlier keypoints.
    """

    X: np.ndarray
    instant: np.ndarray
    scores: np.ndarray
    members: np.ndarray
    inliers: np.ndarray
    valid: np.ndarray
    errors: np.ndarray
    reprojection_error_px: np.ndarray

    def __len__(self) -> int:
        return len(self.X)

    @staticmethod
    def concatenate(parts: list["InstantPersons"], V: int) -> "InstantPersons":
        if not parts:
            J = 17
            return InstantPersons(np.zeros((0, J, 3)), np.zeros(0, int), np.zeros((0, J)), np.zeros((0, V), int),
                                  np.zeros((0, V, J), bool), np.zeros((0, V, J), bool), np.zeros((0, V, J)),
                                  np.zeros(0))
        return InstantPersons(*[np.concatenate([getattr(p, f) for p in parts])
                                for f in InstantPersons.__dataclass_fields__])


def pad_by_camera(instant: np.ndarray, camera: np.ndarray, T: int, V: int) -> tuple[np.ndarray, int]:
    """Slot of each pose in a ``(T, V, n)`` padded layout. ``instant, camera: (N,)`` ->
    flat slot ``(N,)`` into ``T * V * n`` and ``n`` (the most poses of one camera at one instant)."""
    key = instant * V + camera
    order = np.argsort(key, kind="stable")
    counts = np.bincount(key, minlength=T * V)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rank = np.empty(len(key), dtype=np.int64)
    rank[order] = np.arange(len(key)) - starts[key[order]]
    n = int(counts.max()) if len(key) else 0
    return key * n + rank, n


def batched_epipolar_distance(F: np.ndarray, unit: np.ndarray, keypoints: np.ndarray,
                              keypoint_threshold: float, min_common_keypoints: int = 1,
                              no_baseline: np.ndarray | None = None, dtype=np.float32) -> np.ndarray:
    """Eq. 2 for every pair of poses of every instant, as :func:`mvm.core.affinity.epipolar_distance`.

    Args:
        F: ``(V, V, 3, 3)`` fundamental matrices (``F[u, v] @ x_v`` is a line in view ``u``).
        unit: ``(V,)`` the unit of D in each view, pixels (``distance_scale · f``).
        keypoints: ``(T, V, n, J, 3)`` padded poses (padding: confidence 0).
        no_baseline: ``(V, V)`` bool, pairs of cameras without epipolar geometry.
    Returns:
        ``D: (T, V n, V n)``: ``inf`` within a camera, NaN where fewer than
        ``min_common_keypoints`` joints are shared or the cameras have no baseline.
    """
    T, V, n, J, _ = keypoints.shape
    visible = keypoints[..., 2] >= max(keypoint_threshold, 1e-9)                 # (T, V, n, J)
    h = np.concatenate([keypoints[..., :2], np.ones(keypoints.shape[:-1] + (1,))], axis=-1)
    h = np.where(visible[..., None], h, 0.0).astype(dtype)                          # (T, V, n, J, 3)
    hj = np.ascontiguousarray(h.transpose(0, 1, 3, 2, 4))                            # (T, V, J, n, 3)
    # lines[t, u, v, j, :, b] = F[u, v] @ x[t, v, b, j]
    lines = np.matmul(F.astype(dtype)[None, :, :, None], hj[:, None].transpose(0, 1, 2, 3, 5, 4))
    norm = np.sqrt(lines[..., 0, :] ** 2 + lines[..., 1, :] ** 2)                  # (T, U, V, J, n)
    lines *= (1.0 / (unit.astype(dtype)[None, :, None, None, None] * (norm + 1e-30)))[..., None, :]
    d = np.abs(np.matmul(hj[:, :, None], lines))                                     # (T, U, V, J, n, n)
    sums = d.sum(axis=3).transpose(0, 1, 3, 2, 4).reshape(T, V * n, V * n)           # [t, (u,a), (v,b)]
    vis = visible.reshape(T, V * n, J).astype(dtype)
    common = np.matmul(vis, vis.transpose(0, 2, 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        D = (sums + sums.transpose(0, 2, 1)) / (2 * common)
    cam = np.repeat(np.arange(V), n)
    undefined = common < max(min_common_keypoints, 1)
    if no_baseline is not None:
        undefined |= no_baseline[cam[:, None], cam[None, :]][None]
    D[undefined] = np.nan
    D[:, cam[:, None] == cam[None, :]] = np.inf
    return D


def group_instants(cameras: Cameras, detections: Detections, config: Config) -> list[np.ndarray]:
    """Affinity (Eq. 1, 2) and greedy grouping (Algorithm 1) of every instant of ``detections``.
    Returns groups of detection indices (each within one instant), instant by instant."""
    if len(detections) == 0:
        return []
    V = len(cameras)
    instants, local = np.unique(detections.instant, return_inverse=True)
    T = len(instants)
    slot, n = pad_by_camera(local, detections.camera, T, V)
    padded = np.zeros((T * V * n, 17, 3))
    padded[slot] = detections.keypoints
    F = fundamental_matrices(cameras.K, cameras.R, cameras.t)
    centers = cameras.centers
    baseline = np.linalg.norm(centers[:, None] - centers[None], axis=-1)
    no_baseline = baseline <= 1e-9 * max(float(np.median(baseline)), 1e-12)
    D = batched_epipolar_distance(F, config.distance_scale * cameras.focal, padded.reshape(T, V, n, 17, 3),
                                  config.keypoint_threshold, config.min_common_keypoints, no_baseline)
    A_all = affinity(D, config.gamma)
    within = slot % (V * n)
    order = np.argsort(local, kind="stable")
    bounds = np.searchsorted(local[order], np.arange(T + 1))
    groups = []
    for t in range(T):
        rows = order[bounds[t]:bounds[t + 1]]
        pos = within[rows]
        A = A_all[t][np.ix_(pos, pos)]
        for g in greedy_groups(A, detections.score[rows], detections.camera[rows], config.tau,
                               config.min_pose_score, config.min_group_size):
            groups.append(rows[g])
    return groups


def _merge_per_instant(X: np.ndarray, groups: list[np.ndarray], instant_of: np.ndarray,
                       camera: np.ndarray, distance: float) -> list[np.ndarray] | None:
    """:func:`mvm.core.reconstruct.merge_duplicates` within each instant. None when nothing merges."""
    changed = False
    out: list[np.ndarray] = []
    bounds = np.flatnonzero(np.diff(instant_of)) + 1
    for rows in np.split(np.arange(len(groups)), bounds):
        part = [groups[i] for i in rows]
        merged = merge_duplicates(X[rows], part, camera, distance) if len(rows) > 1 else None
        if merged is not None:
            changed = True
            part = merged
        out += part
    return out if changed else None


def reconstruct_batch(cameras: Cameras, detections: Detections, config: Config, prior=None) -> InstantPersons:
    """Reconstruct every instant of ``detections`` (one batch). ``prior``: a
    :class:`mvm.core.prior.PosePrior` or None (refinement on reprojection only)."""
    V = len(cameras)
    groups = group_instants(cameras, detections, config)
    if not groups:
        return InstantPersons.concatenate([], V)
    poses = Poses2D(detections.keypoints, detections.camera, np.arange(len(detections)), detections.score)

    def triangulate(groups):
        obs = gather_groups(cameras, poses, groups, config.keypoint_threshold)
        rng = np.random.default_rng(config.seed)
        return obs, ransac_triangulate(obs, config.ransac_threshold_px, config.ransac_hypotheses,
                                       config.min_views, config.min_parallax_deg, rng, use_ransac=config.ransac)

    instant_of = detections.instant[[g[0] for g in groups]]
    obs, tri = triangulate(groups)
    if config.merge_distance > 0:
        merged = _merge_per_instant(tri.X, groups, instant_of, detections.camera, config.merge_distance)
        if merged is not None:
            groups = merged
            instant_of = detections.instant[[g[0] for g in groups]]
            obs, tri = triangulate(groups)
    X = tri.X
    if config.refine and len(X):
        X = refine_poses(X, obs.xy, obs.conf, obs.P, tri.inliers, prior, config.prior_weight,
                         config.robust_scale_px, config.refine_max_iterations).X
    errors = reprojection_errors(X, obs.xy, obs.P)                                  # (Q, M, J)
    keep = np.isfinite(X).all(-1).sum(-1) >= config.min_person_joints
    Q, M = obs.members.shape
    # From padded group slots (Q, M) to cameras (Q, V).
    cam = np.where(obs.members >= 0, detections.camera[np.maximum(obs.members, 0)], V)   # V: padding
    q = np.repeat(np.arange(Q), M)
    members = np.full((Q, V + 1), -1)
    members[q, cam.reshape(-1)] = obs.members.reshape(-1)
    inliers = np.zeros((Q, V + 1, 17), bool)
    valid = np.zeros((Q, V + 1, 17), bool)
    err = np.full((Q, V + 1, 17), np.nan)
    inliers[q, cam.reshape(-1)] = tri.inliers.reshape(Q * M, 17)
    valid[q, cam.reshape(-1)] = tri.valid.reshape(Q * M, 17)
    err[q, cam.reshape(-1)] = np.where(tri.valid, errors, np.nan).reshape(Q * M, 17)
    inliers, valid, err, members = inliers[:, :V], valid[:, :V], err[:, :V], members[:, :V]
    scores = np.where(tri.inliers, obs.conf, 0).sum(1) / np.maximum(tri.inliers.sum(1), 1)
    used = np.where(inliers, err, 0.0)
    n_used = inliers.sum((1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        person_err = np.where(n_used > 0, used.sum((1, 2)) / n_used, np.nan)
    order = np.argsort(instant_of[keep], kind="stable")
    pick = np.flatnonzero(keep)[order]
    return InstantPersons(X[pick], instant_of[pick], scores[pick], members[pick], inliers[pick],
                          valid[pick], err[pick], person_err[pick])


def load_prior(config: Config, prior=None):
    """The pose prior for the refinement: ``prior``, else the shipped one, else None (with a
    warning: the refinement then fits the reprojection error only)."""
    if prior is not None or not config.refine or config.prior_weight <= 0:
        return prior
    try:
        from mvm.core.prior import PosePrior

        return PosePrior.load()
    except (ImportError, InputError, OSError) as e:
        log.warning("pose prior unavailable (%s); refining on reprojection only", e)
        return None


def reconstruct_instants(cameras: Cameras, detections: Detections, config: Config | None = None,
                         prior=None, batch_size: int = 64,
                         progress: Callable[[int, int], None] | None = None) -> InstantPersons:
    """Reconstruct the persons of every instant of ``detections``, ``batch_size`` instants at a time.

    ``progress(done, total)`` is called after each batch with counts of instants.
    """
    config = config or Config()
    if len(detections) and (detections.camera.min() < 0 or detections.camera.max() >= len(cameras)):
        raise ValueError(f"detections.camera: expected indices in [0, {len(cameras)}), "
                         f"got {detections.camera.min()}..{detections.camera.max()}")
    # With few cameras the distinct view pairs are few: twice their number of random two-view
    # hypotheses finds an all-inlier pair as surely as the default, at a fraction of the cost.
    V = len(cameras)
    config = config.replace(ransac_hypotheses=max(1, min(config.ransac_hypotheses, V * (V - 1))))
    prior = load_prior(config, prior)
    instants = np.unique(detections.instant)
    order = np.argsort(detections.instant, kind="stable")
    sorted_instant = detections.instant[order]
    parts = []
    with threadpool_limits(limits=1, user_api="blas"):
        for start in range(0, len(instants), batch_size):
            chunk = instants[start:start + batch_size]
            lo, hi = np.searchsorted(sorted_instant, [chunk[0], chunk[-1] + 1])
            rows = order[lo:hi]
            result = reconstruct_batch(cameras, detections.subset(rows), config, prior)
            # Members index the batch: map them back to ``detections``.
            result.members = np.where(result.members >= 0, rows[np.maximum(result.members, 0)], -1)
            parts.append(result)
            if progress is not None:
                progress(min(start + batch_size, len(instants)), len(instants))
    return InstantPersons.concatenate(parts, len(cameras))
