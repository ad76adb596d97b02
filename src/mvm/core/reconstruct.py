"""The reconstruction of one scene: affinity -> grouping -> triangulation -> refinement."""
from __future__ import annotations

import logging
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from mvm.core.affinity import affinity, affinity_bytes, appearance_similarity, epipolar_distance
from mvm.core.association import associate, frame_sequence
from mvm.core.config import Config
from mvm.core.matching import greedy_groups
from mvm.core.refine import refine_poses
from mvm.core.scene import Persons3D, Scene
from mvm.core.triangulate import gather_groups, ransac_triangulate
from mvm.errors import InputError
from mvm.eval.metrics import reprojection_errors, scene_quality

log = logging.getLogger(__name__)


@dataclass
class Result:
    """The reconstruction of a scene.

    Attributes:
        persons: the reconstructed persons (members index ``scene.poses``).
        metrics: the paper's quality metrics (``scene_quality``) plus ``refine_fallbacks``.
        timings: seconds per stage.
        warnings: one sentence per degenerate condition met (no parallax, too few views,
            points behind the cameras, refinement fallbacks...), also logged.
    """

    scene: Scene
    persons: Persons3D
    metrics: dict
    timings: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def default_prior():
    """The shipped GMM pose prior, or None if it cannot be loaded."""
    from mvm.core.prior import PosePrior

    return PosePrior.load()


def validate_scene(scene: Scene, source: str | None = None) -> None:
    """Refuse a scene whose numbers the geometry cannot use: non-finite or singular cameras,
    non-finite keypoints, confidences outside [0, 1], views out of range. Raises
    :class:`InputError` naming ``source`` (default the scene's name) and the first bad entry."""
    source = source or scene.name
    cameras, poses = scene.cameras, scene.poses
    for name in ("K", "R", "t"):
        value = getattr(cameras, name)
        bad = ~np.isfinite(value).reshape(len(cameras), value[0].size if len(value) else 0).all(1)
        if bad.any():
            v = int(np.argmax(bad))
            raise InputError(source, f"cameras[{v}].{name}", f"non-finite value in camera {cameras.names[v]!r}")
    with np.errstate(all="ignore"):
        focal_ok = (cameras.K[:, 0, 0] > 0) & (cameras.K[:, 1, 1] > 0) & np.isfinite(1.0 / cameras.K[:, 0, 0]) \
            & np.isfinite(1.0 / cameras.K[:, 1, 1])
        rotation_err = np.abs(cameras.R @ cameras.R.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2), initial=0)
        det = np.linalg.det(cameras.R) if len(cameras) else np.zeros(0)
    if not focal_ok.all():
        v = int(np.argmin(focal_ok))
        raise InputError(source, f"cameras[{v}].K", f"focal length must be > 0, got {cameras.K[v, 0, 0]:g}, {cameras.K[v, 1, 1]:g}")
    bad_rotation = (rotation_err > 1e-4) | (det < 0)
    if bad_rotation.any():
        v = int(np.argmax(bad_rotation))
        raise InputError(source, f"cameras[{v}].R", f"not a rotation matrix (camera {cameras.names[v]!r})")
    if len(poses) and (poses.view.min() < 0 or poses.view.max() >= len(cameras)):
        n = int(np.argmax((poses.view < 0) | (poses.view >= len(cameras))))
        raise InputError(source, f"poses[{n}].view", f"view {poses.view[n]} out of range (0..{len(cameras) - 1})")
    bad = ~np.isfinite(poses.keypoints).all(axis=(1, 2))
    if bad.any():
        n = int(np.argmax(bad))
        raise InputError(source, f"annotations[id={poses.ids[n]}].keypoints", "non-finite value")
    conf = poses.keypoints[:, :, 2]
    bad = ((conf < 0) | (conf > 1)).any(1) | ~np.isfinite(poses.score) | (poses.score < 0)
    if bad.any():
        n = int(np.argmax(bad))
        raise InputError(source, f"annotations[id={poses.ids[n]}]", "confidence or score outside [0, 1] or not finite")


def check_affinity_memory(n_poses: int, appearance: bool, config: Config, source: str | None) -> None:
    """Refuse, before any work, a scene whose affinity needs more than ``max_affinity_bytes``
    (:func:`mvm.core.affinity.affinity_bytes`: ``4 N²`` bytes, ``8 N²`` with appearance)."""
    need = affinity_bytes(n_poses, appearance)
    if need > config.max_affinity_bytes:
        raise InputError(source, "annotations",
                         f"{n_poses} 2D poses need {need / 2**20:.0f} MiB for the affinity matrix, more than "
                         f"max_affinity_bytes = {config.max_affinity_bytes / 2**20:.0f} MiB; raise the limit "
                         f"(--set max_affinity_bytes=...) or split the scene into smaller ones")


def match(scene: Scene, config: Config) -> list[np.ndarray]:
    """Affinity (Eq. 1, 2) and greedy grouping (Algorithm 1): groups of pose indices.

    Memory: one ``(N, N)`` float32 matrix (D, turned into A in place), plus the ``(N, N)``
    appearance similarity when descriptors are used; see :func:`check_affinity_memory`.
    """
    poses, cameras = scene.poses, scene.cameras
    D = epipolar_distance(cameras, poses.keypoints, poses.view, config.keypoint_threshold,
                          config.distance_scale, config.min_common_keypoints)
    S = appearance_similarity(poses.appearance if config.use_appearance else None, len(poses))
    A = affinity(D, config.gamma, S, out=D)
    del S
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
    from mvm.core.keypoints import FLIP_PERMUTATION, LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER

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
        prior: a :class:`mvm.core.prior.PosePrior`; default the shipped one when refining.
        groups: precomputed groups of pose indices (skips matching and the association in 3D),
            e.g. from a baseline or the true grouping.
    """
    config = config or Config()
    validate_scene(scene)
    check_affinity_memory(len(scene.poses), config.use_appearance and scene.poses.appearance is not None,
                          config, scene.name)
    # The hot paths are many small products: BLAS threads only contend with each other.
    with threadpool_limits(limits=1, user_api="blas"):
        return _reconstruct(scene, config, prior, groups)


def _scene_warnings(scene: Scene, config: Config) -> list[str]:
    """Degenerate conditions visible before any work."""
    poses, cameras = scene.poses, scene.cameras
    warnings_ = []
    if len(poses) == 0:
        return ["no 2D poses: nothing to reconstruct"]
    used = np.unique(poses.view)
    if len(used) < max(config.min_group_size, config.min_views):
        warnings_.append(f"2D poses in {len(used)} view(s) only, fewer than min_group_size = {config.min_group_size} "
                         f"or min_views = {config.min_views}: no person can be reconstructed")
    centers = cameras.centers[used]
    if len(used) > 1:
        spread = np.linalg.norm(centers - centers.mean(0), axis=1).max()
        depth = np.linalg.norm(cameras.t[used], axis=1).max()
        if spread <= 1e-9 * max(depth, 1e-12):
            warnings_.append(f"all {len(used)} views share one camera centre (no parallax): nothing can be triangulated")
    return warnings_


def _triangulation_warnings(tri, config: Config) -> list[str]:
    """Joints with enough 2D keypoints that were not triangulated, by reason."""
    if not len(tri.X):
        return []
    observed = tri.valid.sum(axis=1) >= config.min_views                      # (P, J)
    missing = observed & ~np.isfinite(tri.X).all(-1)
    out = []
    if missing.any():
        out.append(f"{int(missing.sum())} of {int(observed.sum())} observed joints left unreconstructed "
                   f"(too few consistent views in front of the cameras, or rays spanning less than "
                   f"min_parallax_deg = {config.min_parallax_deg:g}°)")
    return out


def _refine(X, obs, tri, config: Config, prior) -> tuple[np.ndarray, int]:
    """Refinement with a fallback: a person whose refined pose is not finite, or a solve that
    fails outright, keeps its triangulation. Returns the poses and the number of fallbacks."""
    has_obs = tri.inliers.any(axis=(1, 2))
    try:
        with np.errstate(all="ignore"):
            refined = refine_poses(X, obs.xy, obs.conf, obs.P, tri.inliers, prior, config.prior_weight,
                                   config.robust_scale_px, config.refine_max_iterations)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError, ZeroDivisionError) as e:
        log.warning("refinement failed (%s); kept the triangulation of every person", e)
        return X, int(has_obs.sum())
    X_new = refined.X
    fallback = refined.fallback.copy()
    broken = (np.isfinite(X).all(-1) & ~np.isfinite(X_new).all(-1)).any(-1)     # a joint lost or inf
    fallback |= broken
    X_new = np.where(fallback[:, None, None], X, X_new)
    return X_new, int(fallback.sum())


def _reconstruct(scene: Scene, config: Config, prior, groups) -> Result:
    timings = {}
    warnings_ = _scene_warnings(scene, config)
    t = time.perf_counter()
    given = groups is not None
    if groups is None:
        groups = match(scene, config)
    timings["matching_s"] = time.perf_counter() - t

    t = time.perf_counter()

    def triangulate(groups, initial=None):
        obs = gather_groups(scene.cameras, scene.poses, groups, config.keypoint_threshold)
        rng = np.random.default_rng(config.seed)
        hypotheses = config.ransac_hypotheses if initial is None else config.association_hypotheses
        with np.errstate(all="ignore"):                  # degenerate rays give NaN, left null
            return obs, ransac_triangulate(obs, config.ransac_threshold_px, hypotheses,
                                           config.min_views, config.min_parallax_deg, rng,
                                           use_ransac=config.ransac, initial=initial)

    obs, tri = triangulate(groups)
    associate_3d = config.association == "3d" and not given          # merges duplicates itself
    if config.merge_distance > 0 and not associate_3d:
        merged = merge_duplicates(tri.X, groups, scene.poses.view, config.merge_distance)
        if merged is not None:
            log.info("%s: merged %d duplicate group(s)", scene.name, len(groups) - len(merged))
            groups = merged
            obs, tri = triangulate(groups)
    timings["triangulation_s"] = time.perf_counter() - t
    t = time.perf_counter()
    if associate_3d:
        groups, (obs, tri) = associate(
            scene.poses.keypoints, scene.poses.view, scene.cameras.P, scene.cameras.size, groups, triangulate,
            lambda X, g: merge_duplicates(X, g, scene.poses.view, config.merge_distance) if config.merge_distance > 0 else None,
            lambda rest: match(Scene(scene.name, scene.cameras, scene.poses.subset(rest)), config),
            gate=config.association_gate, max_iterations=config.association_iterations,
            min_group_size=config.min_group_size, min_support=config.association_min_support,
            max_proportion_deviation=config.association_max_proportion_deviation,
            min_person_joints=config.min_person_joints, keypoint_threshold=config.keypoint_threshold,
            min_common_keypoints=config.min_common_keypoints, eligible=scene.poses.score >= config.min_pose_score,
            sequence=frame_sequence(scene.cameras.names) if config.video_order else None, triangulated=(obs, tri))
    timings["association_s"] = time.perf_counter() - t

    warnings_ += _triangulation_warnings(tri, config)

    t = time.perf_counter()
    X = tri.X
    fallbacks = 0
    if config.refine and len(X):
        X, fallbacks = _refine(X, obs, tri, config, default_prior() if prior is None else prior)
        if fallbacks:
            warnings_.append(f"refinement diverged for {fallbacks} person(s): kept their triangulation")
    timings["refinement_s"] = time.perf_counter() - t
    X = np.where(np.isfinite(X).all(-1, keepdims=True), X, np.nan)        # never inf

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
        reprojection_error_px=np.where(inliers.any((1, 2)) & np.isfinite(per_person_err), per_person_err, np.nan),
    )
    n_matched = int(sum(len(m) for m in members))
    metrics = scene_quality(X[keep], errors[keep], inliers, valid, len(scene.poses), n_matched)
    metrics = {k: (v if not isinstance(v, float) or np.isfinite(v) else float("nan")) for k, v in metrics.items()}
    metrics["refine_fallbacks"] = fallbacks
    timings["total_s"] = sum(timings.values())
    if len(scene.poses) and not len(groups) and not warnings_:
        warnings_.append(f"no 2D poses could be matched across views into groups of min_group_size = "
                         f"{config.min_group_size} (affinity below tau = {config.tau:g})")
    elif len(scene.poses) and not len(persons) and not warnings_:
        warnings_.append(f"{len(groups)} group(s) matched, none with min_person_joints = {config.min_person_joints} "
                         f"reconstructed joints")
    for w in warnings_:
        log.warning("%s: %s", scene.name, w)
    return Result(scene, persons, metrics, timings, warnings_)


def reconstruct_dir(path: str | Path, config: Config | None = None, output: str = "mvm",
                    prior=None) -> Result:
    """Read a scene directory, reconstruct it and write ``<path>/<output>/poses3d.json``."""
    from mvm.io.files import LockTimeout, exclusive_lock, remove_stale_temporaries
    from mvm.io.scene_dir import poses3d_document, read_scene, write_poses3d

    config = config or Config()
    path = Path(path)
    t = time.perf_counter()
    scene = read_scene(path)
    read_s = time.perf_counter() - t
    validate_scene(scene, str(path))
    check_affinity_memory(len(scene.poses), config.use_appearance and scene.poses.appearance is not None,
                          config, str(path / "poses2d.json"))
    result = reconstruct(scene, config, prior)
    result.timings = {"read_s": read_s, **result.timings}
    document = poses3d_document(result.persons, scene.poses, result.metrics,
                                {"warnings": list(result.warnings),
                                 "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
                                 "config": asdict(config)})
    out_dir = path / output
    # Runs on the same scene may compute at once; writing is one at a time, and the temporary
    # files of a killed run are removed by the next one.
    try:
        with exclusive_lock(out_dir, config.lock_timeout_s):
            remove_stale_temporaries(out_dir, "poses3d.json")
            write_poses3d(out_dir / "poses3d.json", document)
    except LockTimeout:
        raise InputError(out_dir, None, f"another mvm run has been writing here for more than "
                                        f"{config.lock_timeout_s:g} s (lock_timeout_s)") from None
    return result
