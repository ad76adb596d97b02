"""The rig driver of the reconstruction core (:mod:`mvm.core.pipeline`): many instants of a
synchronized rig at once.

Every instant is a static scene whose views are the ``V`` cameras: the 2D poses carry their
``instant`` (:class:`mvm.core.scene.Poses2D`), and the pipeline matches and merges within each
instant while triangulation and refinement treat the persons of a whole batch of instants as one
vectorized problem (they are independent). This module only lays the result out per camera.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mvm.core.affinity import with_measured_unit
from mvm.core.blas import one_blas_thread
from mvm.core.config import Config
from mvm.core.duplicates import group_blocks
from mvm.core.pipeline import Reconstruction, reconstruct_poses
from mvm.core.prior import load_prior
from mvm.core.reconstruct import scene_config
from mvm.core.scene import Cameras, Poses2D
from mvm.parallel import fork_map_ranges

log = logging.getLogger(__name__)


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

    def take(self, index: np.ndarray) -> InstantPersons:
        """The persons ``index: (K,)`` (indices or a boolean mask), in that order."""
        return InstantPersons(*[getattr(self, f)[index] for f in InstantPersons.__dataclass_fields__])

    @staticmethod
    def concatenate(parts: list[InstantPersons], V: int) -> InstantPersons:
        if not parts:
            J = 17
            return InstantPersons(np.zeros((0, J, 3)), np.zeros(0, int), np.zeros((0, J)), np.zeros((0, V), int),
                                  np.zeros((0, V, J), bool), np.zeros((0, V, J), bool), np.zeros((0, V, J)),
                                  np.zeros(0))
        return InstantPersons(*[np.concatenate([getattr(p, f) for p in parts])
                                for f in InstantPersons.__dataclass_fields__])


def rig_poses(keypoints: np.ndarray, instant: np.ndarray, camera: np.ndarray, score: np.ndarray) -> Poses2D:
    """2D poses of many instants of a rig. ``keypoints: (N, 17, 3)`` undistorted pixels and
    confidence; ``instant, camera, score: (N,)``. The ids are the pose indices."""
    return Poses2D(keypoints, camera, np.arange(len(np.asarray(camera).reshape(-1))), score, instant=instant)


def by_camera(rec: Reconstruction, poses: Poses2D, V: int) -> InstantPersons:
    """The kept persons of ``rec``, group slots ``(Q, M)`` laid out per camera ``(Q, V)``, sorted by instant."""
    obs, tri, stats = rec.obs, rec.tri, rec.stats
    Q, M = obs.members.shape
    cam = np.where(obs.members >= 0, poses.view[np.maximum(obs.members, 0)], V).reshape(-1)   # V: padding
    q = np.repeat(np.arange(Q), M)
    members = np.full((Q, V + 1), -1)
    members[q, cam] = obs.members.reshape(-1)
    inliers = np.zeros((Q, V + 1, 17), bool)
    valid = np.zeros((Q, V + 1, 17), bool)
    err = np.full((Q, V + 1, 17), np.nan)
    inliers[q, cam] = tri.inliers.reshape(Q * M, 17)
    valid[q, cam] = tri.valid.reshape(Q * M, 17)
    err[q, cam] = np.where(tri.valid, stats.errors, np.nan).reshape(Q * M, 17)
    instant_of = group_blocks(poses, rec.groups)
    pick = np.flatnonzero(stats.keep)[np.argsort(instant_of[stats.keep], kind="stable")]
    return InstantPersons(stats.X[pick], instant_of[pick], stats.scores[pick], members[pick, :V],
                          inliers[pick, :V], valid[pick, :V], err[pick, :V], stats.reprojection_error_px[pick])


def reconstruct_batch(cameras: Cameras, poses: Poses2D, config: Config, prior=None) -> InstantPersons:
    """Reconstruct every instant of ``poses`` (one batch; ``poses.instant`` set). ``prior`` as
    :func:`mvm.core.prior.load_prior` resolves it."""
    rec = reconstruct_poses(cameras, poses, config, prior)
    if not rec.groups:
        return InstantPersons.concatenate([], len(cameras))
    return by_camera(rec, poses, len(cameras))


def reconstruct_instants(cameras: Cameras, poses: Poses2D, config: Config | None = None,
                         prior=None, batch_size: int = 32,
                         progress: Callable[[int, int], None] | None = None,
                         workers: int | None = None) -> InstantPersons:
    """Reconstruct the persons of every instant of ``poses`` (``poses.view``: the camera,
    ``poses.instant`` set), ``batch_size`` instants at a time, the batches split in contiguous
    runs over ``workers`` processes (:func:`mvm.parallel.fork_map`; default: the cores available).

    ``progress(done, total)`` is called with counts of instants after each batch of this
    process's share (the first), then once all shares are done.

    ``config``'s settings left to the driver take the scenes' defaults
    (:func:`mvm.core.reconstruct.scene_config`) unless resolved: the rig driver gives its own
    (:func:`mvm.rig.reconstruct_rig.instants_config`).
    """
    config = scene_config(config)
    if poses.instant is None:
        raise ValueError("poses.instant: expected the instant of every pose, got None")
    if len(poses) and (poses.view.min() < 0 or poses.view.max() >= len(cameras)):
        raise ValueError(f"poses.view: expected camera indices in [0, {len(cameras)}), "
                         f"got {poses.view.min()}..{poses.view.max()}")
    # With few cameras the RANSAC of a joint tries each of its pairs of views once
    # (mvm.core.triangulate): C(5, 2) = 10 two-view hypotheses for 5 cameras.
    prior = load_prior(config, prior)
    config = with_measured_unit(cameras, poses, config)          # the capture's noise, once for every batch
    instants = np.unique(poses.instant)
    order = np.argsort(poses.instant, kind="stable")
    sorted_instant = poses.instant[order]

    def run(batches: range, report: Callable[[int, int], None] | None) -> list[InstantPersons]:
        parts = []
        for b in batches:
            batch = instants[b * batch_size:(b + 1) * batch_size]
            lo, hi = np.searchsorted(sorted_instant, [batch[0], batch[-1] + 1])
            rows = order[lo:hi]
            result = reconstruct_batch(cameras, poses.subset(rows), config, prior)
            # Members index the batch: map them back to ``poses``.
            result.members = np.where(result.members >= 0, rows[np.maximum(result.members, 0)], -1)
            parts.append(result)
            if report is not None:
                report(min((b + 1) * batch_size, len(instants)), len(instants))
        return parts

    # Whole batches per worker: the result does not depend on the number of workers.
    with one_blas_thread():
        parts = fork_map_ranges(lambda batches: run(batches, progress if batches.start == 0 else None),
                                -(-len(instants) // batch_size), max(1, 32 // batch_size), workers)
    if progress is not None and len(parts) > 1:
        progress(len(instants), len(instants))
    return InstantPersons.concatenate([p for part in parts for p in part], len(cameras))
