"""The reconstruction of one scene: affinity -> grouping -> triangulation -> refinement."""
from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

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
    timings = {}
    t = time.perf_counter()
    if groups is None:
        groups = match(scene, config)
    timings["matching_s"] = time.perf_counter() - t

    t = time.perf_counter()
    rng = np.random.default_rng(config.seed)
    obs = gather_groups(scene.cameras, scene.poses, groups, config.keypoint_threshold)
    tri = ransac_triangulate(obs, config.ransac_threshold_px, config.ransac_hypotheses,
                             config.min_views, config.min_parallax_deg, rng)
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
