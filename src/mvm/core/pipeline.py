"""The reconstruction pipeline, once for every driver: match -> triangulate -> merge duplicates
(or, with ``association = "3d"``, the association consistent in 3D, which merges itself) ->
refine (with a fallback) -> summarize.

Arrays in, arrays out, no I/O. The 2D poses are split into independent *blocks*
(:meth:`mvm.core.scene.Poses2D.blocks`): a scene of one moving camera is one block, a batch of
rig instants has one block per instant. Matching and merging stay within a block;
triangulation and refinement treat the persons of every block as one set (they are
independent), so a batch of instants costs one vectorized solve; :func:`refine_all` does the
same for the persons of many scenes (:func:`triangulate_poses` of each, then one refinement).

Each step is a function of the previous step's arrays, so that a step is one call between two
others: :func:`associate_poses` changes ``groups`` and returns their new triangulation; the
drivers complete missing joints (:mod:`mvm.core.completion`) after :func:`refine_with_fallback`.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field

import numpy as np

from mvm.core.affinity import block_pose_affinity, pose_affinity, with_measured_unit
from mvm.core.association import assign_poses, associate, frame_sequence, visible_frames
from mvm.core.config import Config
from mvm.core.duplicates import ASSOCIATION_QUANTILE, merge_groups
from mvm.core.image_units import in_person_sizes
from mvm.core.keyframes import frame_windows, spread_views
from mvm.core.keypoints import stray_joints
from mvm.core.matching import greedy_groups
from mvm.core.matching.greedy import greedy_groups_blocks
from mvm.core.prior import load_prior
from mvm.core.quality import reprojection_errors
from mvm.core.refine import refine_poses
from mvm.core.refine_units import noise_factor, noise_threshold, prior_weights
from mvm.core.scene import Cameras, Poses2D
from mvm.core.support import drop_unsupported
from mvm.core.triangulate import GroupObservations, Triangulation, gather_groups, ransac_triangulate, residual_sigma
from mvm.errors import InputError

log = logging.getLogger(__name__)


#: The instants of a rig are matched together, as many at a time as fit this many pairs of
#: poses (padded to the largest instant): one affinity ``(B, n, n)`` and one greedy grouping
#: advancing in every instant at once. An instant larger than this is matched alone.
MATCH_BATCH_PAIRS = 2**16


def _batches(blocks: list[np.ndarray], max_pairs: int) -> list[list[np.ndarray]]:
    """Consecutive blocks in batches of at most ``max_pairs`` padded pairs (a larger block alone)."""
    batches: list[list[np.ndarray]] = []
    size = 0
    for rows in blocks:
        n = max(size, len(rows))
        if not batches or n * n * (len(batches[-1]) + 1) > max_pairs:
            batches.append([])
            n = len(rows)
        batches[-1].append(rows)
        size = n
    return batches


def match(cameras: Cameras, poses: Poses2D, config: Config) -> list[np.ndarray]:
    """Affinity (Eq. 1, 2) and greedy grouping (Algorithm 1) within each block of ``poses``.

    Returns groups of pose indices (each within one block), block by block. Memory: one
    ``(n, n)`` float32 matrix for a scene of ``n`` poses (see :func:`mvm.core.affinity.affinity_bytes`),
    ``17 ×`` :data:`MATCH_BATCH_PAIRS` numbers for a rig (a larger instant: as a scene).
    The instants of a rig whose grouping is final (no association in 3D after it) give the
    poses of a group too small back to the groups seeded after it (``release`` of
    :func:`mvm.core.matching.greedy.greedy_groups`).
    """
    groups: list[np.ndarray] = []
    rig = poses.instant is not None and config.association != "3d"         # the grouping is final
    for batch in _batches(poses.blocks(), MATCH_BATCH_PAIRS):
        if poses.instant is None or len(batch) == 1 and len(batch[0]) ** 2 > MATCH_BATCH_PAIRS:
            rows = batch[0]
            if not _may_group(poses.view[rows], poses.score[rows], config):
                continue
            sub = poses if len(rows) == len(poses) else poses.subset(rows)
            found = [greedy_groups(pose_affinity(cameras, sub, config), sub.score, sub.view, config.tau,
                                   config.min_pose_score, config.min_group_size, release=rig)]
        else:
            index = np.full((len(batch), max(len(rows) for rows in batch)), -1)
            for b, rows in enumerate(batch):
                index[b, :len(rows)] = rows
            pad = index < 0
            found = greedy_groups_blocks(block_pose_affinity(cameras, poses, index, config),
                                         np.where(pad, 0.0, poses.score[index]), np.where(pad, -1, poses.view[index]),
                                         config.tau, config.min_pose_score, config.min_group_size, release=rig)
        groups += [rows[g] for rows, block in zip(batch, found) for g in block]
    return groups


def keyframe_rows(cameras: Cameras, poses: Poses2D, config: Config) -> np.ndarray | None:
    """The poses the grouping of a scene compares: those of ``config.keyframes`` well-spread
    frames (:func:`mvm.core.keyframes.spread_views`) of a longer video, the association in 3D
    (or with ``association = "paper"``, one round of its assignment, :func:`extend_groups`)
    bringing the others in; None for all of them (a video of ``keyframes`` frames or fewer, or
    the instants of a rig). ``config``: resolved for the scene driver."""
    if poses.instant is not None:
        return None
    used = np.unique(poses.view)
    if len(used) <= config.keyframes:
        return None
    key = spread_views(used, config.keyframes, _sequence(cameras, poses, config), cameras.centers)
    return np.flatnonzero(np.isin(poses.view, key))


def match_keyframes(cameras: Cameras, poses: Poses2D, config: Config, rows: np.ndarray | None) -> list[np.ndarray]:
    """:func:`match` on the poses ``rows`` of :func:`keyframe_rows` (None: all of them, a short
    video). Memory: the affinity of those poses only, whatever the length of the video."""
    if rows is None:
        return match(cameras, poses, config)
    return [rows[g] for g in match(cameras, poses.subset(rows), config)]


def extend_groups(cameras: Cameras, poses: Poses2D, groups: list[np.ndarray], config: Config,
                  triangulated: tuple[GroupObservations, Triangulation], threshold: np.ndarray | None,
                  rows: np.ndarray) -> tuple[list[np.ndarray], tuple[GroupObservations, Triangulation]]:
    """The paper's groups of a long video's keyframes (``rows``: their poses,
    :func:`keyframe_rows`) extended to its other frames: each other pose to the person
    ``triangulated`` whose reprojection explains it (:func:`mvm.core.association.assign_poses`),
    then every person triangulated again from all its views (``threshold`` as
    :func:`triangulate_groups` takes it). Linear in the frames; the keyframes' groups stay."""
    others = np.setdiff1d(np.flatnonzero(poses.score >= config.min_pose_score), rows)
    if not groups or not len(others):
        return groups, triangulated
    groups = assign_poses(poses.keypoints, poses.view, cameras.P, triangulated[1].X, groups, others,
                          gate=config.association_gate, min_person_joints=config.min_person_joints,
                          keypoint_threshold=config.keypoint_threshold,
                          min_common_keypoints=config.min_common_keypoints,
                          sequence=_sequence(cameras, poses, config))
    return groups, triangulate_groups(cameras, poses, groups, config, threshold=threshold)


def match_windows(cameras: Cameras, poses: Poses2D, config: Config) -> list[np.ndarray]:
    """:func:`match` within windows of ``config.keyframes`` consecutive frames of a scene
    (:func:`mvm.core.keyframes.frame_windows`), each window a block: time and memory linear in
    the frames. Poses within one window (a short video): :func:`match` itself."""
    if poses.instant is not None or not len(poses):
        return match(cameras, poses, config)
    window = frame_windows(poses.view, config.keyframes, _sequence(cameras, poses, config))
    if window.max() == 0:
        return match(cameras, poses, config)
    groups = match(cameras, dataclasses.replace(poses, instant=window), config)
    return [g for g, keep in zip(groups, _window_support(cameras, poses, groups, window, config)) if keep]


def _window_support(cameras: Cameras, poses: Poses2D, groups: list[np.ndarray], window: np.ndarray,
                    config: Config) -> np.ndarray:
    """``(P,)`` bool: the groups of :func:`match_windows` that triangulate to a person
    (``min_person_joints``) explaining at least ``association_min_support`` of their window's
    frames it projects into. A person the keyframes missed is seen all along its window; a
    cluster of a few false poses is not, and is dropped before the association pairs it with
    every pose of the video."""
    if not groups:
        return np.zeros(0, dtype=bool)
    _, tri = triangulate_groups(cameras, poses, groups, config)
    keep = np.isfinite(tri.X).all(-1).sum(-1) >= config.min_person_joints
    for w in np.unique(window[[g[0] for g in groups]]):
        mine = np.flatnonzero(window[[g[0] for g in groups]] == w)
        views = np.unique(poses.view[window == w])
        with np.errstate(all="ignore"):
            visible = visible_frames(tri.X[mine], cameras.P[views], cameras.size[views])
        count = np.array([len(groups[i]) for i in mine])
        keep[mine] &= count >= config.association_min_support * visible
    return keep


def _sequence(cameras: Cameras, poses: Poses2D, config: Config) -> np.ndarray | None:
    """``(V,)`` position of each view in the video, or None: unordered photos, or a rig."""
    return frame_sequence(cameras.names) if config.video_order and poses.instant is None else None


def _may_group(view: np.ndarray, score: np.ndarray, config: Config) -> bool:
    """Whether poses of ``view, score: (n,)`` can make a group: a group holds one pose per view
    and at least ``min_group_size`` poses, all of score ``min_pose_score`` or more, so poses
    eligible in fewer views make none (e.g. the few false positives the association leaves
    over), and their affinity need not be computed."""
    eligible = np.where(np.isfinite(score), score, 0.0) >= config.min_pose_score     # as the grouping reads it
    return np.count_nonzero(np.bincount(view[eligible])) >= max(config.min_group_size, 1)


#: Working memory of the RANSAC triangulation per group, view slot, joint and hypothesis
#: (bytes; measured about 62: the projections, depths, errors and costs of every hypothesis).
TRIANGULATION_BYTES_PER_ENTRY = 64


def triangulation_bytes(groups: list[np.ndarray], joints: int, hypotheses: int, max_views: int | None = None) -> int:
    """Peak memory of :func:`triangulate_groups`, at most: groups are padded to the largest one's
    ``M`` views, and each of the ``H`` hypotheses of every joint is scored in ``S = min(M, max_views)``
    view slots, so ``P · (M + S · H) · J ·`` :data:`TRIANGULATION_BYTES_PER_ENTRY` bytes (the
    ``M``: the padded keypoints and cameras themselves). ``H`` is ``hypotheses`` (0: no RANSAC),
    at most the ``S (S - 1) / 2`` pairs of views (:func:`mvm.core.triangulate.ransac_triangulate`).
    The bound is reached when the hypotheses are kept (the first triangulation of a scene); the
    others work a few groups at a time (:data:`mvm.core.triangulate.TRIANGULATION_CHUNK`)."""
    widest = max((len(g) for g in groups), default=0)
    scored = widest if max_views is None else min(widest, int(max_views))
    H = min(int(hypotheses), max(1, scored * (scored - 1) // 2)) if hypotheses > 0 else 0
    return len(groups) * (widest + scored * H) * int(joints) * TRIANGULATION_BYTES_PER_ENTRY


def check_triangulation_memory(groups: list[np.ndarray], joints: int, hypotheses: int, config: Config) -> None:
    """Refuse, before it is allocated, a triangulation that needs more than ``max_affinity_bytes``
    (:func:`triangulation_bytes`): one :class:`~mvm.errors.InputError` line naming the setting."""
    need = triangulation_bytes(groups, joints, hypotheses, config.max_triangulation_views)
    if need > config.max_affinity_bytes:
        widest = max(len(g) for g in groups)
        raise InputError(None, "max_affinity_bytes",
                         f"triangulating {len(groups)} candidate persons of up to {widest} views with {hypotheses} "
                         f"RANSAC hypotheses needs {need / 2**20:.0f} MiB, more than max_affinity_bytes = "
                         f"{config.max_affinity_bytes / 2**20:.0f} MiB; raise the limit "
                         "(--set max_affinity_bytes=...), lower ransac_hypotheses or max_triangulation_views, "
                         "or split the scene into smaller ones")


def triangulate_groups(cameras: Cameras, poses: Poses2D, groups: list[np.ndarray],
                       config: Config, initial: np.ndarray | None = None,
                       threshold: np.ndarray | None = None,
                       again: tuple[GroupObservations, Triangulation] | None = None,
                       keep_hypotheses: bool = False) -> tuple[GroupObservations, Triangulation]:
    """Per-joint RANSAC triangulation of ``P`` groups; degenerate rays give NaN joints.
    ``initial: (P, J, 3)``, the groups' previous 3D poses, replaces all but
    ``association_hypotheses`` of the random hypotheses. ``threshold: (N,)`` the RANSAC
    threshold of each pose's block (:func:`block_thresholds`; None: ``ransac_threshold``).
    ``again``: this function's result for the same ``groups`` and ``initial``, made with
    ``keep_hypotheses``: its hypotheses are selected from at ``threshold``, not drawn and scored
    again (the same result, a third of the time).
    Memory: :func:`triangulation_bytes`, refused beyond ``max_affinity_bytes`` before it is taken."""
    hypotheses = config.ransac_hypotheses if initial is None else min(config.ransac_hypotheses,
                                                                       config.association_hypotheses)
    check_triangulation_memory(groups, poses.keypoints.shape[1],
                               hypotheses + (initial is not None) if config.ransac else 0, config)
    obs = gather_groups(cameras, poses, groups, config.keypoint_threshold) if again is None else again[0]
    if threshold is not None:
        threshold = threshold[np.array([g[0] for g in groups], dtype=np.int64)]
    with np.errstate(all="ignore"):
        return obs, ransac_triangulate(obs, config.ransac_threshold if threshold is None else threshold,
                                       hypotheses, config.min_views, config.min_parallax_deg, config.seed,
                                       use_ransac=config.ransac, initial=initial,
                                       max_views=config.max_triangulation_views,
                                       hypotheses_scored=None if again is None else again[1].hypotheses,
                                       keep_hypotheses=keep_hypotheses)


def block_thresholds(poses: Poses2D, groups: list[np.ndarray], obs: GroupObservations, tri: Triangulation,
                     config: Config) -> np.ndarray | None:
    """``(N,)`` the RANSAC threshold of each pose's block, ``ransac_threshold_sigmas`` times the
    noise :func:`mvm.core.triangulate.residual_sigma` measures in the block's triangulation
    ``obs, tri`` of ``groups`` (at least one), within half to twice ``ransac_threshold`` (which
    a block without a measure keeps). None where the threshold is held (no RANSAC, or sigmas 0)."""
    if not config.ransac or config.ransac_threshold_sigmas <= 0:
        return None
    pose_block = np.zeros(len(poses), dtype=np.int64) if poses.instant is None else \
        np.unique(poses.instant, return_inverse=True)[1].reshape(-1)
    blocks = int(pose_block.max(initial=-1)) + 1
    group_block = pose_block[np.array([g[0] for g in groups], dtype=np.int64)]
    return noise_threshold(residual_sigma(obs, tri, group_block, blocks), config)[pose_block]



#: What a refinement that fails outright raises (bad numbers the fallback cannot catch person by person).
_SOLVE_FAILURES = (ValueError, np.linalg.LinAlgError, FloatingPointError, ZeroDivisionError)


def refine_with_fallback(X: np.ndarray, obs: GroupObservations, tri: Triangulation, config: Config,
                         prior=None) -> tuple[np.ndarray, np.ndarray]:
    """Refinement (Eq. bundle) with a fallback: a person whose refined pose is worse, not
    finite or lost a joint, or every person when the solve fails outright, keeps its
    triangulation. ``X: (P, J, 3)``; ``prior`` as :func:`mvm.core.prior.load_prior` resolves it.
    Returns the poses and ``fallback: (P,)`` bool."""
    try:
        return _refine(X, obs.xy, obs.conf, obs.P, tri.inliers, obs.size, tri.threshold, obs.centers, config, prior)
    except _SOLVE_FAILURES as e:
        log.warning("refinement failed (%s); kept the triangulation of every person", e)
        return X, tri.inliers.any(axis=(1, 2))


def _refine(X, xy, conf, P, inliers, size, threshold, centers, config: Config, prior
            ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`refine_with_fallback` of the arrays of :class:`GroupObservations` and
    :class:`Triangulation`, a solve that fails outright raised. The reprojection residuals are
    in person sizes (``size: (P, M)`` px, :func:`mvm.core.image_units.in_person_sizes`) times
    each person's :func:`~mvm.core.refine_units.noise_factor` (``threshold: (P,)`` its RANSAC
    threshold), the unit of ``robust_scale`` and ``prior_weight``: both follow the noise
    measured in the person's scene; the prior's weight follows its views' spread too
    (:func:`~mvm.core.refine_units.prior_weights`, ``centers: (P, M, 3)`` the views' cameras)."""
    weights = prior_weights(config, X, centers, inliers.any(-1))
    xy, P = in_person_sizes(xy, P, size * noise_factor(threshold, config)[:, None])
    with np.errstate(all="ignore"):
        refined = refine_poses(X, xy, conf, P, inliers, load_prior(config, prior), weights,
                               config.robust_scale, config.refine_max_iterations)
    broken = (np.isfinite(X).all(-1) & ~np.isfinite(refined.X).all(-1)).any(-1)     # a joint lost or inf
    fallback = refined.fallback | broken
    return np.where(fallback[:, None, None], X, refined.X), fallback


@dataclass
class PersonStats:
    """Per-person statistics of ``P`` groups (all of them; ``keep`` marks the persons).

    Attributes:
        X: ``(P, J, 3)`` joints, NaN (never inf) where not reconstructed.
        keep: ``(P,)`` bool, at least ``min_person_joints`` joints reconstructed.
        errors: ``(P, M, J)`` reprojection error of each group slot's keypoint, px.
        scores: ``(P, J)`` mean confidence of the inlier keypoints.
        reprojection_error_px: ``(P,)`` mean error over the inlier keypoints, NaN without any.
    """

    X: np.ndarray
    keep: np.ndarray
    errors: np.ndarray
    scores: np.ndarray
    reprojection_error_px: np.ndarray


def summarize(X: np.ndarray, obs: GroupObservations, tri: Triangulation, config: Config) -> PersonStats:
    """:class:`PersonStats` of the poses ``X: (P, J, 3)`` against the groups' keypoints."""
    X = np.where(np.isfinite(X).all(-1, keepdims=True), X, np.nan)
    if len(X):
        errors = reprojection_errors(X, obs.xy, obs.P)                      # (P, M, J)
    else:
        errors = np.zeros((0, 0, X.shape[1] if X.ndim == 3 else 17))
    keep = np.isfinite(X).all(-1).sum(-1) >= config.min_person_joints
    inliers = tri.inliers
    scores = np.where(inliers, obs.conf, 0).sum(1) / np.maximum(inliers.sum(1), 1)
    per_person = np.where(inliers, errors, 0).sum((1, 2)) / np.maximum(inliers.sum((1, 2)), 1)
    usable = inliers.any((1, 2)) & np.isfinite(per_person)
    return PersonStats(X, keep, errors, scores, np.where(usable, per_person, np.nan))


@dataclass
class Triangulated:
    """What the pipeline made of ``P`` groups of 2D poses before the refinement.

    Attributes:
        groups: ``P`` arrays of pose indices, block by block.
        obs, tri: the groups' padded keypoints and their triangulation.
        timings: seconds per stage (``matching_s``, ``triangulation_s``, ``association_s``).
    """

    groups: list[np.ndarray]
    obs: GroupObservations
    tri: Triangulation
    timings: dict = field(default_factory=dict)


@dataclass
class Reconstruction:
    """What the pipeline made of ``P`` groups of 2D poses (drivers pick ``stats.keep``).

    Attributes:
        groups: ``P`` arrays of pose indices, block by block.
        obs, tri: the groups' padded keypoints and their triangulation.
        stats: :class:`PersonStats` of the final poses.
        fallback: ``(P,)`` bool, persons that kept their triangulation (refinement diverged).
        timings: seconds per stage (``matching_s``, ``triangulation_s``, ``refinement_s``).
    """

    groups: list[np.ndarray]
    obs: GroupObservations
    tri: Triangulation
    stats: PersonStats
    fallback: np.ndarray
    timings: dict = field(default_factory=dict)


def associate_poses(cameras: Cameras, poses: Poses2D, groups: list[np.ndarray], triangulated,
                    config: Config, threshold: np.ndarray | None = None
                    ) -> tuple[list[np.ndarray], tuple[GroupObservations, Triangulation]]:
    """:func:`mvm.core.association.associate` with the settings of ``config``: every 2D pose to
    the triangulated person that explains it, within its block; the order of the frames is a
    cue for a scene (``video_order``), never for the cameras of a rig. ``threshold``: as
    :func:`triangulate_groups` takes it."""
    sequence = _sequence(cameras, poses, config)
    return associate(
        poses.keypoints, poses.view, cameras.P, cameras.size, groups,
        lambda g, initial=None: triangulate_groups(cameras, poses, g, config, initial, threshold),
        lambda X, g: merge_groups(X, g, poses, config, ASSOCIATION_QUANTILE),
        lambda rest: match_windows(cameras, poses.subset(rest), config),
        gate=config.association_gate, max_iterations=config.association_iterations,
        min_group_size=config.min_group_size,
        min_support=config.association_min_support if poses.instant is None else config.rig_min_support,
        max_proportion_deviation=config.association_max_proportion_deviation,
        min_person_joints=config.min_person_joints, max_bone_ratio=config.max_bone_ratio,
        keypoint_threshold=config.keypoint_threshold,
        min_common_keypoints=config.min_common_keypoints, eligible=poses.score >= config.min_pose_score,
        pose_scene=poses.instant, sequence=sequence, triangulated=triangulated)


def reconstruct_poses(cameras: Cameras, poses: Poses2D, config: Config, prior=None,
                      groups: list[np.ndarray] | None = None) -> Reconstruction:
    """The pipeline on ``poses`` seen by ``cameras``: :func:`triangulate_poses`, then
    :func:`refine_all` (refinement with its fallback, per-person statistics)."""
    return refine_all([triangulate_poses(cameras, poses, config, groups)], config, prior)[0]


def triangulate_poses(cameras: Cameras, poses: Poses2D, config: Config,
                      groups: list[np.ndarray] | None = None) -> Triangulated:
    """The pipeline up to the refinement: groups (``groups``, else :func:`match`),
    triangulation (again at each block's own RANSAC threshold, :func:`block_thresholds`),
    merging of duplicates, the association consistent in 3D (``association = "3d"``, not for
    given groups). ``config``: the settings its driver resolved
    (:attr:`mvm.core.config.Config.resolved`)."""
    assert config.resolved, "triangulate_poses takes the settings its driver resolved (Config.for_driver)"
    timings = {}
    t = time.perf_counter()
    given = groups is not None
    if not given:
        config = with_measured_unit(cameras, poses, config)
    keyframes = None if given else keyframe_rows(cameras, poses, config)
    if groups is None:
        groups = match_keyframes(cameras, poses, config, keyframes)
    timings["matching_s"] = time.perf_counter() - t
    t = time.perf_counter()
    obs, tri = triangulate_groups(cameras, poses, groups, config, keep_hypotheses=True)
    threshold = block_thresholds(poses, groups, obs, tri, config) if groups else None
    if threshold is not None:
        obs, tri = triangulate_groups(cameras, poses, groups, config, threshold=threshold, again=(obs, tri))
    tri.hypotheses = None                                                # their memory, no longer needed
    associate_3d = config.association == "3d" and not given              # merges duplicates itself
    merged = None if associate_3d else merge_groups(tri.X, groups, poses, config)
    if merged is not None:
        log.info("merged %d duplicate group(s)", len(groups) - len(merged))
        groups = merged
        obs, tri = triangulate_groups(cameras, poses, groups, config, threshold=threshold)
    if keyframes is not None and not associate_3d:                      # the paper's grouping of a long video
        groups, (obs, tri) = extend_groups(cameras, poses, groups, config, (obs, tri), threshold, keyframes)
    timings["triangulation_s"] = time.perf_counter() - t
    if associate_3d:
        t = time.perf_counter()
        groups, (obs, tri) = associate_poses(cameras, poses, groups, (obs, tri), config, threshold)
        timings["association_s"] = time.perf_counter() - t
    if poses.instant is not None and not associate_3d and not given:
        drop_unsupported(cameras, groups, tri, config)
    drop_stray_joints(tri, config)
    return Triangulated(groups, obs, tri, timings)


def drop_stray_joints(tri: Triangulation, config: Config) -> None:
    """Leave the joints of :func:`mvm.core.keypoints.stray_joints` (bones over ``max_bone_ratio``
    times their proportion) unreconstructed in ``tri``, in place, before the refinement: kept,
    such a joint pulls its neighbours after it there (the heavy 18-camera dome: 14.13 mm with the
    check after the refinement, 14.01 with it before)."""
    if config.max_bone_ratio > 0 and len(tri.X):
        stray = stray_joints(tri.X, config.max_bone_ratio)                  # (P, J)
        tri.X[stray] = np.nan
        tri.inliers &= ~stray[:, None, :]


def refine_all(parts: list[Triangulated], config: Config, prior=None) -> list[Reconstruction]:
    """Refine the persons of every part (:func:`refine_with_fallback`) and summarize each part.

    Persons are independent, and one vectorized solve of many costs little more than one of a
    few: the persons of all parts whose groups are padded to the same number of views are
    solved together (on a rig exported as one-instant scenes, a quarter to a third of the time
    of a solve per scene), each with the numbers it would get alone to rounding (1e-15). A
    solve of several parts that fails outright raises
    (:func:`mvm.core.reconstruct.reconstruct_many` then solves each part alone). A part's
    ``refinement_s`` is its persons' share of the time."""
    refined = [(p.tri.X, np.zeros(len(p.groups), dtype=bool)) for p in parts]
    seconds = np.zeros(len(parts))
    if config.refine:
        for members in _same_width(parts):
            t = time.perf_counter()
            for i, result in zip(members, _refine_together([parts[i] for i in members], config, prior)):
                refined[i] = result
            persons = np.array([len(parts[i].groups) for i in members], dtype=float)
            seconds[members] = (time.perf_counter() - t) * persons / max(persons.sum(), 1.0)
    return [Reconstruction(p.groups, p.obs, p.tri, summarize(X, p.obs, p.tri, config), fallback,
                           dict(p.timings, refinement_s=float(s)))
            for p, (X, fallback), s in zip(parts, refined, seconds)]


def _same_width(parts: list[Triangulated]) -> list[list[int]]:
    """Indices of the parts with persons, by the number of views their groups are padded to."""
    widths: dict[int, list[int]] = {}
    for i, p in enumerate(parts):
        if len(p.groups):
            widths.setdefault(p.obs.xy.shape[1], []).append(i)
    return list(widths.values())


def _refine_together(parts: list[Triangulated], config: Config, prior) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(X, fallback)`` of each part, its refinement solved with the others' (parts of one
    width; one part alone gets :func:`refine_with_fallback`'s fallback for a failed solve)."""
    if len(parts) == 1:
        return [refine_with_fallback(parts[0].tri.X, parts[0].obs, parts[0].tri, config, prior)]
    arrays = [np.concatenate(a) for a in zip(*[(p.tri.X, p.obs.xy, p.obs.conf, p.obs.P, p.tri.inliers,
                                                    p.obs.size, p.tri.threshold, p.obs.centers) for p in parts])]
    X, fallback = _refine(*arrays, config, prior)
    bounds = np.cumsum([len(p.groups) for p in parts])[:-1]
    return list(zip(np.split(X, bounds), np.split(fallback, bounds)))
