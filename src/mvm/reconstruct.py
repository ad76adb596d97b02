"""The reconstruction of one scene: affinity -> grouping -> triangulation -> refinement."""
from __future__ import annotations

import logging
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from .affinity import affinity, appearance_similarity, epipolar_distance
from .config import Config
from .matching import greedy_groups
from .metrics import reprojection_errors, scene_quality
from .refine import refine_poses
from .scene import Persons3D, Scene
from .triangulate import gather_groups, ransac_triangulate

log = logging.getLogger(__name__)


@dataclass
class Result:
    """The reconstruction of a scene.

    Attributes:
        persons: the reconstructed persons (members index ``scene.poses``).
        metrics: the paper's quality metrics (``scene_quality``) plus ``refine_fallbacks``.
        timings: seconds per stage.
    """

    scene: Scene
    persons: Persons3D
    metrics: dict
    timings: dict = field(default_factory=dict)


def default_prior():
    """The shipped GMM pose prior, or None if it cannot be loaded."""
    from .prior import PosePrior

    return PosePrior.load()


def match(scene: Scene, config: Config) -> list[np.ndarray]:
    """Affinity (Eq. 1, 2) and greedy grouping (Algorithm 1): groups of pose indices."""
    poses, cameras = scene.poses, scene.cameras
    D = epipolar_distance(cameras, poses.keypoints, poses.view, config.keypoint_threshold,
                          config.distance_scale, config.min_common_keypoints)
    S = appearance_similarity(poses.appearance if config.use_appearance else None, len(poses))
    A = affinity(D, config.gamma, S)
    return greedy_groups(A, poses.score, poses.view, config.tau, config.min_pose_score,
                         config.min_group_size)


def merge_duplicates(X: np.ndarray, groups: list[np.ndarray], view: np.ndarray,
                     max_relative_distance: float) -> list[np.ndarray] | None:
    """Merge groups whose triangulated poses coincide (a person split into two groups).

    Two persons are duplicates when their mean joint distance, over the joints both have, is
    below ``max_relative_distance`` times the larger torso length (hip to shoulder), which
    keeps the test free of the model's unknown scale; also when one is the mirror of the other
    (left and right exchanged: a group of left-right swapped detections). The smaller group's
    poses join the larger one, except those from views the larger group already has;
    triangulation then treats a swapped keypoint as any other outlier.

    ``X: (P, J, 3)``; ``groups``: pose indices; ``view: (N,)``. Returns the new groups, or None
    when nothing merges.
    """
    from .keypoints import FLIP_PERMUTATION, LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER

    P = len(X)
    if P < 2:
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        torso = np.nanmean(np.stack([np.linalg.norm(X[:, LEFT_SHOULDER] - X[:, LEFT_HIP], axis=-1),
                                     np.linalg.norm(X[:, RIGHT_SHOULDER] - X[:, RIGHT_HIP], axis=-1)]), axis=0)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)                      # all-NaN rows
        diff = np.linalg.norm(X[:, None] - X[None], axis=-1)                 # (P, P, J)
        mirrored = np.linalg.norm(X[:, None] - X[None][:, :, FLIP_PERMUTATION], axis=-1)
        mean = np.fmin(np.nanmean(diff, axis=-1), np.nanmean(mirrored, axis=-1))
        scale = np.fmax(torso[:, None], torso[None])
        close = (mean < max_relative_distance * scale) & ~np.eye(P, dtype=bool)
    if not close.any():
        return None
    order = np.argsort([-len(g) for g in groups], kind="stable")
    absorbed = np.zeros(P, dtype=bool)
    merged = {int(p): list(groups[p]) for p in range(P)}
    for p in order:
        if absorbed[p]:
            continue
        for q in order:
            if q == p or absorbed[q] or not close[p, q] or len(groups[q]) > len(merged[p]):
                continue
            views = set(view[merged[p]].tolist())
            merged[p] += [m for m in groups[q] if view[m] not in views]
            absorbed[q] = True
    return [np.array(merged[p]) for p in range(P) if not absorbed[p]]


def reconstruct(scene: Scene, config: Config | None = None, prior=None,
                groups: list[np.ndarray] | None = None) -> Result:
    """Reconstruct the persons of ``scene``.

    Args:
        scene: cameras and 2D poses.
        config: thresholds (default :class:`Config`).
        prior: a :class:`mvm.prior.PosePrior`; default the shipped one when refining.
        groups: precomputed groups of pose indices (skips matching), e.g. from a baseline.
    """
    config = config or Config()
    # The hot paths are many small products: BLAS threads only contend with each other.
    with threadpool_limits(limits=1, user_api="blas"):
        return _reconstruct(scene, config, prior, groups)


def _reconstruct(scene: Scene, config: Config, prior, groups) -> Result:
    timings = {}
    t = time.perf_counter()
    if groups is None:
        groups = match(scene, config)
    timings["matching_s"] = time.perf_counter() - t

    t = time.perf_counter()

    def triangulate(groups):
        obs = gather_groups(scene.cameras, scene.poses, groups, config.keypoint_threshold)
        rng = np.random.default_rng(config.seed)
        return obs, ransac_triangulate(obs, config.ransac_threshold_px, config.ransac_hypotheses,
                                       config.min_views, config.min_parallax_deg, rng,
                                       use_ransac=config.ransac)

    obs, tri = triangulate(groups)
    if config.merge_distance > 0:
        merged = merge_duplicates(tri.X, groups, scene.poses.view, config.merge_distance)
        if merged is not None:
            log.info("%s: merged %d duplicate group(s)", scene.name, len(groups) - len(merged))
            groups = merged
            obs, tri = triangulate(groups)
    timings["triangulation_s"] = time.perf_counter() - t

    t = time.perf_counter()
    X = tri.X
    fallbacks = 0
    if config.refine and len(X):
        prior = default_prior() if prior is None else prior
        refined = refine_poses(X, obs.xy, obs.conf, obs.P, tri.inliers, prior, config.prior_weight,
                               config.robust_scale_px, config.refine_max_iterations)
        X = refined.X
        fallbacks = int(refined.fallback.sum())
    timings["refinement_s"] = time.perf_counter() - t

    errors = reprojection_errors(X, obs.xy, obs.P) if len(X) else np.zeros((0, 0, 17))
    keep = np.isfinite(X).all(-1).sum(-1) >= config.min_person_joints
    inliers, valid = tri.inliers[keep], tri.valid[keep]
    members = [np.sort(g) for g, k in zip(groups, keep) if k]
    scores = np.where(inliers, obs.conf[keep], 0).sum(1) / np.maximum(inliers.sum(1), 1)
    err_used = np.where(inliers, errors[keep], 0)
    per_person_err = err_used.sum((1, 2)) / np.maximum(inliers.sum((1, 2)), 1)
    persons = Persons3D(
        keypoints3d=X[keep], scores=scores, members=members,
        views_per_joint=inliers.sum(1), outliers_per_joint=(valid & ~inliers).sum(1),
        reprojection_error_px=np.where(inliers.any((1, 2)), per_person_err, np.nan),
    )
    n_matched = int(sum(len(m) for m in members))
    metrics = scene_quality(X[keep], errors[keep], inliers, valid, len(scene.poses), n_matched)
    metrics["refine_fallbacks"] = fallbacks
    timings["total_s"] = sum(timings.values())
    return Result(scene, persons, metrics, timings)


def reconstruct_dir(path: str | Path, config: Config | None = None, output: str = "mvm",
                    prior=None) -> Result:
    """Read a scene directory, reconstruct it and write ``<path>/<output>/poses3d.json``."""
    from .io.scene_dir import poses3d_document, read_scene, write_poses3d

    config = config or Config()
    t = time.perf_counter()
    scene = read_scene(path)
    read_s = time.perf_counter() - t
    result = reconstruct(scene, config, prior)
    result.timings = {"read_s": read_s, **result.timings}
    document = poses3d_document(result.persons, scene.poses, result.metrics,
                                {"timings_s": {k: round(v, 4) for k, v in result.timings.items()},
                                 "config": asdict(config)})
    write_poses3d(Path(path) / output / "poses3d.json", document)
    return result
