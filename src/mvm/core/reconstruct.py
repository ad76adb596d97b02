"""A static scene's reconstruction: its checks, the pipeline (:mod:`mvm.core.pipeline`) on its
2D poses as one block, the persons, the paper's quality metrics and warnings. No I/O: reading and
writing a scene directory is :func:`mvm.scenes.reconstruct_dir`."""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from mvm.core.affinity import affinity_bytes
from mvm.core.blas import one_blas_thread
from mvm.core.config import Config
from mvm.core.pipeline import Reconstruction, Triangulated, keyframe_rows, refine_all, triangulate_poses
from mvm.core.quality import scene_quality
from mvm.core.refine_units import noise_factor, prior_weights
from mvm.core.scene import Persons3D, Scene
from mvm.errors import InputError

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
        raise InputError(source, f"cameras[{v}].K",
                         f"focal length must be > 0, got {cameras.K[v, 0, 0]:g}, {cameras.K[v, 1, 1]:g}")
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


def check_affinity_memory(scene: Scene, config: Config, source: str | None) -> None:
    """Refuse, before any work, a scene whose affinity needs more than ``max_affinity_bytes``
    (:func:`mvm.core.affinity.affinity_bytes`: ``4 N²`` bytes, ``8 N²`` with appearance, for
    the ``N`` poses the grouping compares: those of the keyframes of a long video,
    :func:`mvm.core.pipeline.keyframe_rows`). ``config``: resolved for the scene driver."""
    rows = keyframe_rows(scene.cameras, scene.poses, config)
    n_poses = len(scene.poses) if rows is None else len(rows)
    need = affinity_bytes(n_poses, config.use_appearance and scene.poses.appearance is not None)
    if need > config.max_affinity_bytes:
        raise InputError(source, "annotations",
                         f"{n_poses} 2D poses need {need / 2**20:.0f} MiB for the affinity matrix, more than "
                         f"max_affinity_bytes = {config.max_affinity_bytes / 2**20:.0f} MiB; raise the limit "
                         "(--set max_affinity_bytes=...), lower keyframes (--set keyframes=...) or split the "
                         "scene into smaller ones")


def scene_config(config: Config | None = None) -> Config:
    """The settings the scene driver runs with: ``config`` (default :class:`Config`) with the
    scenes' defaults of the settings left to the driver (:meth:`Config.for_driver`). Resolved
    once, at each entry (:func:`reconstruct`, :func:`reconstruct_many`,
    :func:`mvm.scenes.reconstruct_dir`, the scene stage); the steps below take them so."""
    return (config or Config()).for_driver("scene")


def reconstruct(scene: Scene, config: Config | None = None, prior=None,
                groups: list[np.ndarray] | None = None) -> Result:
    """Reconstruct the persons of ``scene``.

    Args:
        scene: cameras and 2D poses.
        config: thresholds (default :class:`Config`; settings left to the driver take the
            scenes' defaults, :func:`scene_config`).
        prior: a :class:`mvm.core.prior.PosePrior`; default as :func:`mvm.core.prior.load_prior`.
        groups: precomputed groups of pose indices (skips matching and the association in 3D),
            e.g. from a baseline or the true grouping.
    """
    config = scene_config(config)
    # The hot paths are many small products: BLAS threads only contend with each other.
    with one_blas_thread():
        [rec] = refine_all([_triangulated(scene, config, groups)], config, prior)
        return _finished(scene, config, rec, prior)


def reconstruct_many(scenes: list[Scene], config: Config | None = None, prior=None) -> list[Result | Exception]:
    """:func:`reconstruct` of each of ``scenes``, their refinements solved together
    (:func:`mvm.core.pipeline.refine_all`): the numbers of :func:`reconstruct` to rounding, in
    a fraction of the time where scenes are small (the one-instant scenes of a rig). Returns,
    in order, each scene's :class:`Result` or the exception it raised: one scene's failure is
    its own."""
    config = scene_config(config)
    outcomes: list = [None] * len(scenes)
    parts = {}
    with one_blas_thread():
        for i, scene in enumerate(scenes):
            try:
                parts[i] = _triangulated(scene, config, None)
            except Exception as e:                        # noqa: BLE001 - this scene's failure, in its place
                outcomes[i] = e
        try:
            recs = dict(zip(parts, refine_all(list(parts.values()), config, prior)))
        except Exception:                                 # noqa: BLE001 - each scene solved alone below,
            recs = {}                                     # its failure its own
        for i, part in parts.items():
            try:
                rec = recs[i] if i in recs else refine_all([part], config, prior)[0]
                outcomes[i] = _finished(scenes[i], config, rec, prior)
            except Exception as e:                        # noqa: BLE001 - this scene's failure, in its place
                outcomes[i] = e
    return outcomes


def _triangulated(scene: Scene, config: Config, groups: list[np.ndarray] | None) -> Triangulated:
    """The scene checked, and its pipeline up to the refinement."""
    validate_scene(scene)
    if groups is None:                                    # given groups need no affinity
        check_affinity_memory(scene, config, scene.name)
    return triangulate_poses(scene.cameras, scene.poses, config, groups)


def _finished(scene: Scene, config: Config, rec: Reconstruction, prior) -> Result:
    """The scene's result from its refined reconstruction, completed when ``config.complete``."""
    result = _scene_result(scene, config, rec)
    if config.complete and len(result.persons):
        from mvm.core.completion import complete_persons
        from mvm.core.prior import shipped_prior

        persons = result.persons
        persons.keypoints3d, persons.flags = complete_persons(persons.keypoints3d, prior or shipped_prior(),
                                                              config.min_person_joints)
    return result


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
            warnings_.append(f"all {len(used)} views share one camera centre (no parallax): "
                             "nothing can be triangulated")
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


def _persons(rec: Reconstruction) -> Persons3D:
    """The kept persons of ``rec``, members indexing the scene's poses."""
    keep, inliers = rec.stats.keep, rec.tri.inliers[rec.stats.keep]
    return Persons3D(
        keypoints3d=rec.stats.X[keep], scores=rec.stats.scores[keep],
        members=[np.sort(g) for g, k in zip(rec.groups, keep) if k],
        views_per_joint=inliers.sum(1), outliers_per_joint=(rec.tri.valid[keep] & ~inliers).sum(1),
        reprojection_error_px=rec.stats.reprojection_error_px[keep])


def _outcome_warnings(scene: Scene, config: Config, rec: Reconstruction, persons: Persons3D) -> list[str]:
    """Why a scene with 2D poses gave no group, or no person."""
    if len(scene.poses) and not len(rec.groups):
        return [f"no 2D poses could be matched across views into groups of min_group_size = "
                f"{config.min_group_size} (affinity below tau = {config.tau:g})"]
    if len(scene.poses) and not len(persons):
        return [f"{len(rec.groups)} group(s) matched, none with min_person_joints = {config.min_person_joints} "
                f"reconstructed joints"]
    return []


def effective_thresholds(config: Config, threshold: np.ndarray, size: np.ndarray, slots: np.ndarray,
                         prior_weight: np.ndarray) -> dict:
    """The thresholds the persons of a scene got: the RANSAC threshold (``threshold: (P,)``,
    person sizes; the median), the median person size (``size: (P, M)`` px of the view slots
    ``slots: (P, M)`` bool), what the RANSAC threshold and the refinement's robust scale came to
    in pixels (the medians over the slots; the robust scale follows the scene's noise,
    :func:`mvm.core.refine_units.noise_factor`) and the prior weight the refinement used (person
    sizes² per nat, the median; ``prior_weight: (P,)`` in the persons' noise units,
    :func:`mvm.core.refine_units.prior_weights`).
    NaN without any person."""
    if not slots.any():
        return dict.fromkeys(("ransac_threshold", "person_size_px", "ransac_threshold_px", "robust_scale_px",
                              "prior_weight"), float("nan"))
    per_slot = np.broadcast_to(threshold[:, None], slots.shape)[slots]
    factor = noise_factor(per_slot, config)
    return {"ransac_threshold": float(np.median(threshold)), "person_size_px": float(np.median(size[slots])),
            "ransac_threshold_px": float(np.median(per_slot * size[slots])),
            "robust_scale_px": config.robust_scale * float(np.median(factor * size[slots])),
            "prior_weight": float(np.median(prior_weight * noise_factor(threshold, config) ** 2))}


def _scene_result(scene: Scene, config: Config, rec: Reconstruction) -> Result:
    persons = _persons(rec)
    keep = rec.stats.keep
    n_matched = int(sum(len(m) for m in persons.members))
    metrics = scene_quality(persons.keypoints3d, rec.stats.errors[keep], rec.tri.inliers[keep],
                            rec.tri.valid[keep], len(scene.poses), n_matched)
    metrics = {k: (v if not isinstance(v, float) or np.isfinite(v) else float("nan")) for k, v in metrics.items()}
    fallbacks = int(rec.fallback.sum())
    metrics["refine_fallbacks"] = fallbacks
    weights = prior_weights(config, rec.tri.X, rec.obs.centers, rec.tri.inliers.any(-1))
    metrics.update(effective_thresholds(config, rec.tri.threshold[keep], rec.obs.size[keep],
                                        rec.obs.members[keep] >= 0, weights[keep]))
    timings = dict(rec.timings, total_s=sum(rec.timings.values()))
    warnings_ = _scene_warnings(scene, config) + _triangulation_warnings(rec.tri, config)
    if fallbacks:
        warnings_.append(f"refinement diverged for {fallbacks} person(s): kept their triangulation")
    if not warnings_:
        warnings_ = _outcome_warnings(scene, config, rec, persons)
    for w in warnings_:
        log.warning("%s: %s", scene.name, w)
    return Result(scene, persons, metrics, timings, warnings_)
