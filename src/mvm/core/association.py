"""Association consistent in 3D: every 2D pose to the 3D person that explains it best.

The greedy grouping (Algorithm 1) compares 2D poses only through epipolar lines, which leave a
whole line of ambiguity: on a nearly horizontal camera arc, two people at similar heights look
consistent pair by pair. Once a group is triangulated, its 3D pose pins every joint to one
point in each view. This module uses that: it reprojects the persons into every view, assigns
each 2D pose (grouped or not) to the person whose reprojection it matches, at most one pose per
person per view (an optimal assignment per view, with a gate), re-triangulates, and repeats to a
fixed point. Persons whose 3D poses coincide are merged, members that do not fit their person's
triangulation are released (a mixed group splits), and persons that explain too few of the
views they are visible in, or whose bones have no human proportions, are refused. In a video,
a pose's distance to the same person in a neighbouring frame may lower its cost (an optional
cue).

Distances are those of OKS: pixels divided by the person's image size, ``s = sqrt(w h)`` of
the bounding box of its reprojected joints, so one gate serves every distance and resolution
(:mod:`mvm.core.pose_distance`).

Arrays: ``N`` 2D poses, ``J = 17`` joints, ``F`` views (frames, or the cameras of a rig),
``P`` persons. The module is pure: arrays and callables in, groups out.
"""
from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np

from mvm.core.assignment import min_cost_assignment
from mvm.core.body_parts import body_deviation, split_persons
from mvm.core.duplicates import absorb_explained, pose_groups
from mvm.core.geometry import ray_spread_deg
from mvm.core.hiding import sight, unhidden_views
from mvm.core.names import natural_key
from mvm.core.pose_distance import reprojection_cost

#: In the video cue, per-joint distances are clipped to this many gates: a wrong or swapped
#: joint weighs like a few ordinary ones, never like the whole pose.
_CLIP_GATES = 2.0


def assign_per_frame(cost: np.ndarray, pose: np.ndarray, person: np.ndarray, slot: np.ndarray,
                     n_poses: int, gate: float) -> np.ndarray:
    """Each pose to at most one person, each person to at most one pose per slot (a view of
    one scene), minimizing the summed cost among pairs below ``gate``.

    ``cost, pose, person, slot: (K,)`` candidate pairs; ``slot`` is the view (and scene) of the
    pair's pose. Returns ``(n_poses,)`` person of each pose, -1 for none.

    Where every pose's best person is claimed by no other pose of its slot, the best persons
    are the optimum; the other slots are solved by :func:`mvm.core.assignment.min_cost_assignment`.
    """
    out = np.full(n_poses, -1)
    ok = cost < gate
    cost, pose, person, slot = cost[ok], pose[ok], person[ok], slot[ok]
    if not len(cost):
        return out
    order = np.lexsort((cost, pose))                                 # best pair of each pose first
    sorted_pose = pose[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = sorted_pose[1:] != sorted_pose[:-1]
    best = order[first]                                              # (n,) the best pair of each pose
    claim = slot[best].astype(np.int64) * (int(person.max()) + 1) + person[best]      # (slot, person) as one key
    clash_slot = np.zeros(slot.max() + 1, dtype=bool)
    clash_slot[slot[best][_repeated(claim)]] = True
    easy = best[~clash_slot[slot[best]]]
    out[pose[easy]] = person[easy]
    hard = np.flatnonzero(clash_slot[slot])
    if len(hard):
        hard = hard[np.argsort(slot[hard], kind="stable")]
        bounds = np.flatnonzero(np.diff(slot[hard])) + 1
        for rows in np.split(hard, bounds):
            poses_u, r = np.unique(pose[rows], return_inverse=True)
            persons_u, c = np.unique(person[rows], return_inverse=True)
            matrix = np.full((len(poses_u), len(persons_u)), 1e6)
            matrix[r, c] = cost[rows]
            i, j = min_cost_assignment(matrix)
            good = matrix[i, j] < gate
            out[poses_u[i[good]]] = persons_u[j[good]]
    return out


def _repeated(values: np.ndarray) -> np.ndarray:
    """``(n,)`` bool: the entries of ``values: (n,)`` whose value occurs more than once."""
    order = np.argsort(values, kind="stable")
    same = values[order[1:]] == values[order[:-1]]
    repeated = np.zeros(len(values), dtype=bool)
    repeated[order[1:][same]] = True
    repeated[order[:-1][same]] = True
    return repeated


def temporal_cost(keypoints: np.ndarray, frame: np.ndarray, sequence: np.ndarray, assignment: np.ndarray,
                  pose: np.ndarray, person: np.ndarray, size: np.ndarray, keypoint_threshold: float,
                  min_common_keypoints: int, clip: float, max_gap: int) -> np.ndarray:
    """Normalized distance of 2D poses to a person's pose in the nearest frame of a video.

    ``sequence: (F,)`` position of each view in the video; ``assignment: (N,)`` the current
    person of each pose (-1: none). For each candidate pair ``(pose, person)`` of ``(K,)``, the
    nearest other frame within ``max_gap`` positions where ``person`` has a pose gives the
    reference; the distance is the confidence-weighted mean over the joints both poses have of
    the keypoint distances, each clipped to ``clip``, in person sizes ``size: (K,)`` (px).
    Returns ``(K,)``, NaN where the person has no pose near that frame.
    """
    K = len(pose)
    out = np.full(K, np.nan)
    held = np.flatnonzero(assignment >= 0)
    if K == 0 or not len(held):
        return out
    # Persons' poses sorted by (person, position in the video).
    key_person = assignment[held]
    key_pos = sequence[frame[held]]
    order = np.lexsort((key_pos, key_person))
    held, key_person, key_pos = held[order], key_person[order], key_pos[order]
    combined = key_person.astype(np.int64) * (int(sequence.max()) + 2) + key_pos
    here = person.astype(np.int64) * (int(sequence.max()) + 2) + sequence[frame[pose]]
    right = np.searchsorted(combined, here, side="right")            # first position after this frame
    left = np.searchsorted(combined, here, side="left") - 1          # last position before it
    reference = np.full(K, -1)
    gap = np.full(K, np.inf)
    for idx in (left, right):
        inside = (idx >= 0) & (idx < len(held))
        idx_c = np.minimum(np.maximum(idx, 0), len(held) - 1)
        same = inside & (key_person[idx_c] == person)
        g = np.where(same, np.abs(key_pos[idx_c] - sequence[frame[pose]]), np.inf)
        better = (g < gap) & (g <= max_gap) & (g > 0)
        reference = np.where(better, held[idx_c], reference)
        gap = np.where(better, g, gap)
    has = reference >= 0
    a = keypoints[pose[has]]
    b = keypoints[reference[has]]
    conf = np.where((a[..., 2] >= keypoint_threshold) & (b[..., 2] >= keypoint_threshold),
                    np.sqrt(a[..., 2] * b[..., 2]), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.minimum(np.linalg.norm(a[..., :2] - b[..., :2], axis=-1) / size[has, None], clip)
        c = (conf * d).sum(1) / conf.sum(1)
    enough = (conf > 0).sum(1) >= min_common_keypoints
    out[has] = np.where(enough, c, np.nan)
    return out


def visible_frames(X: np.ndarray, P: np.ndarray, image_size: np.ndarray) -> np.ndarray:
    """Number of views in which each person's reprojection lies mostly inside the image.

    ``X: (Q, J, 3)``, ``P: (F, 3, 4)``, ``image_size: (F, 2)``. A person counts in a view when
    at least half its reconstructed joints project in front of the camera and inside the
    image. Returns ``(Q,)`` (:func:`mvm.core.hiding.sight`).

    One camera at the origin looking along z (640 × 480 px); one person in front of it, one behind:

    >>> P = np.array([[[500.0, 0, 320, 0], [0, 500, 240, 0], [0, 0, 1, 0]]])
    >>> X = np.zeros((2, 17, 3)) + [[[0.0, 0.0, 4.0]], [[0.0, 0.0, -4.0]]]
    >>> visible_frames(X, P, np.array([[640.0, 480.0]]))
    array([1, 0])
    """
    return sight(X, P, image_size)[0].sum(1)


def frame_sequence(names: tuple[str, ...] | list[str]) -> np.ndarray:
    """Position of each view in a video from its image name, in natural order
    (:func:`mvm.core.names.natural_key`: ``frame_2`` before ``frame_10``). ``names``: ``F``
    names -> ``(F,)`` int.

    >>> frame_sequence(["f_10.jpg", "f_2.jpg", "f_1.jpg"]).tolist()
    [2, 1, 0]
    """
    order = sorted(range(len(names)), key=lambda i: natural_key(names[i]))
    sequence = np.empty(len(names), dtype=np.int64)
    sequence[order] = np.arange(len(names))
    return sequence


#: Settled: at most this fraction of the poses changed person in a round (the groups before are kept).
SETTLED = 1e-4


def _moved(before: list[np.ndarray], after: list[np.ndarray], N: int) -> int:
    """How many of ``N`` poses changed group from ``before`` to ``after`` (sorted pose indices;
    a group is named by its first pose)."""
    names = [np.array([g[0] if len(g) else -1 for g in groups] + [-1])[pose_groups(groups, N)]
             for groups in (before, after)]                                   # -1 (the last): no group
    return int(np.count_nonzero(names[0] != names[1]))


def _groups_of(assignment: np.ndarray, count: int) -> list[np.ndarray]:
    """Pose indices of each person ``0..count-1`` (sorted)."""
    held = np.flatnonzero(assignment >= 0)
    order = np.argsort(assignment[held], kind="stable")
    held = held[order]
    bounds = np.searchsorted(assignment[held], np.arange(count + 1))
    return [held[bounds[p]:bounds[p + 1]] for p in range(count)]


def associate(keypoints: np.ndarray, frame: np.ndarray, P: np.ndarray, image_size: np.ndarray,
              groups: list[np.ndarray], triangulate: Callable, merge: Callable | None = None,
              seed: Callable | None = None, *,
              gate: float = 0.15, max_iterations: int = 4, min_group_size: int = 3, min_support: float = 0.2,
              max_proportion_deviation: float = 0.25, min_person_joints: int = 5, max_bone_ratio: float = 0.0,
              keypoint_threshold: float = 0.2, min_common_keypoints: int = 3, eligible: np.ndarray | None = None,
              pose_scene: np.ndarray | None = None, sequence: np.ndarray | None = None,
              temporal_weight: float = 0.5, max_gap: int = 3, triangulated=None):
    """Regroup 2D poses so that every group is the set of poses one 3D person explains.

    Args:
        keypoints, frame: ``(N, J, 3)`` px and confidence, ``(N,)`` view; P, image_size: ``(F, 3, 4)``, ``(F, 2)``.
        groups: initial groups of pose indices (e.g. Algorithm 1's), one pose per view each.
        triangulate: ``triangulate(groups, initial=None) -> (observations, triangulation)``,
            ``triangulation.X: (len(groups), J, 3)``; ``initial``, the persons' previous 3D
            poses, is a hypothesis that spares most of RANSAC's random ones.
        merge: ``merge(X, groups) -> groups or None`` joins persons whose 3D poses coincide;
            seed: ``seed(poses) -> groups``, the grouping, run once on the poses left over.
        gate: the largest cost (:func:`reprojection_cost`, person sizes) of an assignment;
            min_group_size, min_support, max_proportion_deviation, max_bone_ratio: :func:`credible`, :func:`_separate`.
        eligible, pose_scene: ``(N,)`` the poses that may be assigned, the scene of each (a rig's instants).
        sequence: ``(F,)`` position of each view in a video, or None: the temporal cue
            (:func:`temporal_cost`, ``temporal_weight``, ``max_gap``) may lower a cost.
        triangulated: the ``triangulate(groups)`` result when already computed.
    Returns ``(groups, triangulate(groups))``, the groups sorted, scene by scene as they came."""
    keypoints = np.asarray(keypoints, dtype=float)
    N = len(keypoints)
    if keypoints.shape[1:] != (17, 3) or frame.shape != (N,):
        raise ValueError(f"associate: expected keypoints (N, 17, 3), frame (N,); got {keypoints.shape}, {frame.shape}")
    eligible = np.ones(N, dtype=bool) if eligible is None else np.asarray(eligible, dtype=bool)
    rig, pose_scene = pose_scene is not None, np.asarray(np.zeros(N) if pose_scene is None else pose_scene, np.int64)
    slot = pose_scene * len(P) + frame                                   # the view (and scene) of each pose
    groups = [np.sort(np.asarray(g)) for g in groups]
    result = triangulate(groups) if triangulated is None else triangulated
    for iteration in range(max_iterations):
        groups, X, seen, split = _separate(triangulate, groups, result, min_common_keypoints, max_bone_ratio)
        groups, X, seen, stale = _merge_persons(merge, X, seen, groups, N)
        if not groups:
            break
        usable = np.isfinite(X).all(-1).sum(-1) >= min_person_joints
        pose, person, cost = _costs(keypoints, frame, P, X, groups, pose_scene, eligible, usable, gate,
                                    keypoint_threshold, min_common_keypoints, sequence, temporal_weight, max_gap)
        assignment = assign_per_frame(cost, pose, person, slot[pose], N, gate)
        new = _groups_of(assignment, len(groups))
        for q in np.flatnonzero(~usable):      # too incomplete to reproject: keeps what nobody took
            new[q] = groups[q][assignment[groups[q]] < 0]
        new = absorb_explained(new, pose, person, cost, slot, gate) or new      # a person seen twice
        keep = credible(new, X, seen, P, image_size, usable, min_group_size, min_support, max_proportion_deviation,
                         max_bone_ratio, agreed=rig, scene=None if rig else np.zeros(len(new), np.int64),
                         view=None if rig or iteration == 0 else frame)         # from the 2nd round: see credible
        new, initial = [g for g, k in zip(new, keep) if k], X[keep]
        if seed is not None and iteration == 0:
            new, initial = _add_missed(new, initial, seed, eligible, pose_scene)
        if len(new) == len(groups) and _moved(groups, new, N) <= SETTLED * N:
            if stale or split:                                           # ``result`` is of other groups
                result = triangulate(groups, X)
            break
        groups = new
        result = triangulate(groups, initial)
    return groups, result


def assign_poses(keypoints: np.ndarray, frame: np.ndarray, P: np.ndarray, X: np.ndarray, groups: list[np.ndarray],
                 candidates: np.ndarray, *, gate: float = 0.15, min_person_joints: int = 5,
                 keypoint_threshold: float = 0.2, min_common_keypoints: int = 3, sequence: np.ndarray | None = None,
                 temporal_weight: float = 0.5, max_gap: int = 3) -> list[np.ndarray]:
    """``groups`` with each of the ``candidates`` (pose indices, in views none of the groups
    has a pose in) added to the person ``X: (Q, J, 3)`` whose reprojection explains it, as one
    round of :func:`associate` assigns (the same costs, gate and assignment per view); the
    groups' own poses stay. Cost linear in the candidates: the frames of a long video beyond
    the keyframes the grouping saw. Arguments as :func:`associate`'s."""
    eligible = np.zeros(len(keypoints), dtype=bool)
    eligible[candidates] = True
    usable = np.isfinite(X).all(-1).sum(-1) >= min_person_joints
    pose, person, cost = _costs(keypoints, frame, P, X, groups, np.zeros(len(keypoints), dtype=np.int64), eligible,
                                usable, gate, keypoint_threshold, min_common_keypoints, sequence, temporal_weight,
                                max_gap)
    taken = _groups_of(assign_per_frame(cost, pose, person, frame[pose], len(keypoints), gate), len(groups))
    return [np.sort(np.concatenate([g, t])) for g, t in zip(groups, taken)]


def _separate(triangulate: Callable, groups: list[np.ndarray], result, min_joints: int,
              max_bone_ratio: float) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, bool]:
    """``(groups, X, seen, split)`` of ``groups`` triangulated as ``result``, where two people
    triangulated as one (:func:`mvm.core.body_parts.body_parts`: a bone over ``max_bone_ratio``
    whose ends no view sees together, parts of ``min_joints`` joints) are split (``split``: then
    ``result`` no longer triangulates ``groups``), each part triangulated from its own poses;
    ``seen: (Q, J)`` as :func:`credible` reads it."""
    X, seen = result[1].X, result[1].inliers.sum(1)
    split = split_persons(groups, X, result[1].inliers, result[0].members, min_joints, max_bone_ratio,
                          result[0].conf > 0) if max_bone_ratio > 0 and groups else None
    if split is None:
        return groups, X, seen, False
    groups, X, person, part = split
    parts, seen = np.flatnonzero(part >= 0), seen[person]
    again = triangulate([groups[q] for q in parts])[1]
    X[parts], seen[parts] = again.X, again.inliers.sum(1)
    return groups, X, seen, True


def _merge_persons(merge: Callable | None, X: np.ndarray, seen: np.ndarray, groups: list[np.ndarray], N: int):
    """``merge`` the persons whose 3D poses coincide: ``(groups, X, seen, stale)``. Each
    merged person keeps the 3D pose (and ``seen: (Q, J)``, see :func:`credible`) of the
    group it has most poses from until it is re-triangulated (``stale``: ``X`` no longer
    triangulates ``groups``)."""
    merged = merge(X, groups) if merge is not None and len(groups) > 1 else None
    if merged is None:
        return groups, X, seen, False
    owner = pose_groups(groups, N)
    survivor = [int(np.bincount(owner[np.asarray(g)][owner[np.asarray(g)] >= 0]).argmax()) for g in merged]
    return [np.sort(np.asarray(g)) for g in merged], X[survivor], seen[survivor], True


def _costs(keypoints, frame, P, X, groups, pose_scene, eligible, usable, gate, keypoint_threshold,
           min_common_keypoints, sequence, temporal_weight, max_gap):
    """The (pose, person) pairs of one scene and their costs: three ``(K,)`` arrays. With a
    video ``sequence``, a pose that continues the person's track in a neighbouring frame may
    get a lower cost (never a higher one), so large motion between frames costs nothing."""
    group_scene = np.array([pose_scene[g[0]] for g in groups])
    pose, person = _candidate_pairs(pose_scene, group_scene, np.flatnonzero(eligible), usable)
    temporal = sequence is not None and temporal_weight > 0
    max_cost = gate / (1 - temporal_weight) if temporal and temporal_weight < 1 else np.inf if temporal else gate
    cost, size = reprojection_cost(keypoints, frame, P, X, pose, person, keypoint_threshold,
                                   min_common_keypoints, swap_above=gate, max_cost=max_cost)
    if temporal:
        current = pose_groups(groups, len(keypoints))
        hope = np.flatnonzero(cost * (1 - temporal_weight) < gate)         # pairs the cue can bring in
        near = temporal_cost(keypoints, frame, np.asarray(sequence), current, pose[hope], person[hope],
                             size[hope], keypoint_threshold, min_common_keypoints, _CLIP_GATES * gate, max_gap)
        blend = (1 - temporal_weight) * cost[hope] + temporal_weight * near
        cost[hope] = np.where(np.isfinite(near), np.fmin(cost[hope], blend), cost[hope])
    return pose, person, cost


#: A person too incomplete to judge its proportions (a head behind others) is judged by its
#: views instead: its best seen joint agreed on by this many of them, at least, ... [views]
HEAD_MIN_AGREED_VIEWS = 6
#: ... spread this wide around it (no false cluster of the crowd benchmarks agrees in more than
#: three views; a person's poses triangulated off, along a short stretch of the arc). [degrees]
HEAD_MIN_SPREAD_DEG = 20.0


def credible(groups: list[np.ndarray], X: np.ndarray, seen: np.ndarray, P: np.ndarray, image_size: np.ndarray,
              usable: np.ndarray, min_group_size: int, min_support: float,
              max_proportion_deviation: float, max_bone_ratio: float = 0.0, agreed: bool = False,
              scene: np.ndarray | None = None, view: np.ndarray | None = None) -> np.ndarray:
    """``(Q,)`` bool, the persons kept: those explaining enough poses and enough of the views
    they project into, and whose body is one (false positives agreeing in a few close views
    triangulate to no body, unless they explain most of their views, as no false cluster does;
    nor does a person none of whose joints three of its views agree on, ``seen: (Q, J)`` the
    inlier views of each of its joints: two views agree on a point whatever they saw). The
    proportions are those of the body without its stray joints (``max_bone_ratio``) and without
    the joints few of its views agree on (:func:`mvm.core.body_parts.body_deviation`).

    ``agreed`` (a rig's instants): a group none of whose joints three views agree on is refused
    even where it explains half of the few views it projects into: a cluster of false poses
    placed where few cameras look (the heavy 18-camera dome: 4-5 false poses, 6-9 cameras; with
    the unit of D grown by the detector's noise they group), while a person of three poses or more
    has a joint three of its cameras see. A hand-held scene keeps the exemption (its frames follow
    one another along an arc: a person of the crowd benchmark was lost without it).

    ``scene: (Q,)`` the scene of each person (a hand-held scene's: a rig's cameras see every
    person from some side): one that explains too few of the views it projects into but has a
    human body (its proportions judged, within ``max_proportion_deviation``) is
    kept when it explains enough of those where no nearer person of its scene hides it
    (:func:`mvm.core.hiding.unhidden_views`; a person behind others for most of a hand-held tour). The
    persons that pass without it are judged as they were; a group of too few bones to judge, or
    of no human body, is never kept so (kept so in a crowd, a cluster of four false poses 24 m
    away and a person's first poses triangulated 1.5 m off changed the rounds that followed, and
    two mixed neighbours were never split). With ``view: (N,)`` the view of each pose, a group
    of too few bones is judged so where its views vouch for it instead (:func:`wide_agreement`:
    a head seen over the crowd, its body hidden; the 20-person crowd of seed 8, two persons
    found in 25 and 12 of 150 frames by the head and an arm: 18 -> 20 of 20). :func:`associate`
    passes ``view`` from its second round: in the first, a fragment of a person dropped gives its
    poses back to the grouping of those left over (:func:`_add_missed`; with the rule in the
    first round too, crowd3 of the crowd benchmark lost two of its 15 persons)."""
    count = np.array([len(g) for g in groups])
    keep = (count >= min_group_size) | (~usable & (count > 0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        inside, box = sight(X, P, image_size, boxes=scene is not None)               # one projection
        visible = inside.sum(1)
        deviation = body_deviation(X, max_bone_ratio, seen)
        weak = usable & (count < min_support * visible)
        human = deviation <= max_proportion_deviation
        if view is not None and (weak & np.isnan(deviation)).any():
            human |= np.isnan(deviation) & wide_agreement(groups, X, seen, P, view, weak)
        weak &= human
        unhidden = unhidden_views(inside, box, X, P, scene, weak) if scene is not None and weak.any() else visible
    keep &= (count >= min_support * unhidden) | ~usable
    keep &= ~((deviation > max_proportion_deviation) & (2 * count < visible))
    keep &= ~((seen.max(-1, initial=0) < min(3, min_group_size)) & ((2 * count < visible) | agreed))
    return keep


def wide_agreement(groups: list[np.ndarray], X: np.ndarray, seen: np.ndarray, P: np.ndarray, view: np.ndarray,
                   among: np.ndarray) -> np.ndarray:
    """``(Q,)`` bool: the persons ``among: (Q,)`` whose best seen joint at least
    :data:`HEAD_MIN_AGREED_VIEWS` of their views agree on (``seen: (Q, J)``) and whose poses'
    views (``view: (N,)``, cameras ``P: (F, 3, 4)``) span at least :data:`HEAD_MIN_SPREAD_DEG`
    around them (``X: (Q, J, 3)``): a person, however little of it is seen. Clusters of false
    poses agree in two or three views; a few poses of one person triangulated off come from a
    short stretch of a tour, whose rays meet anywhere along their depth."""
    count = np.array([len(g) for g in groups])
    wide = among & (seen.max(-1, initial=0) >= HEAD_MIN_AGREED_VIEWS) & (count >= 2)
    if not wide.any():
        return wide
    centers = -np.linalg.solve(P[:, :, :3], P[:, :, 3:])[..., 0]               # (F, 3)
    for q in np.flatnonzero(wide):
        rays = centers[view[groups[q]]] - np.nanmean(X[q], axis=0)
        rays /= np.maximum(np.linalg.norm(rays, axis=-1, keepdims=True), 1e-12)
        wide[q] = ray_spread_deg(rays, np.ones(len(rays), dtype=bool)) >= HEAD_MIN_SPREAD_DEG
    return wide


def _add_missed(groups: list[np.ndarray], initial: np.ndarray, seed: Callable, eligible: np.ndarray,
                pose_scene: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Group once (``seed``) the eligible poses no person explains: persons the grouping missed,
    appended with no previous 3D pose and kept in scene order."""
    taken = np.zeros(len(eligible), dtype=bool)
    for g in groups:
        taken[g] = True
    rest = np.flatnonzero(eligible & ~taken)
    found = [np.sort(rest[g]) for g in seed(rest)] if len(rest) else []
    if not found:
        return groups, initial
    groups = groups + found
    initial = np.concatenate([initial, np.full((len(found),) + initial.shape[1:], np.nan)])
    order = np.argsort([pose_scene[g[0]] for g in groups], kind="stable")
    return [groups[i] for i in order], initial[order]


def _candidate_pairs(pose_scene: np.ndarray, group_scene: np.ndarray, poses: np.ndarray,
                     usable: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every (pose, person) pair of the same scene: two ``(K,)`` index arrays.

    ``pose_scene: (N,)``, ``group_scene: (Q,)``; ``poses``: the eligible pose indices;
    ``usable: (Q,)`` persons that may take poses.
    """
    persons = np.flatnonzero(usable)
    if not len(persons) or not len(poses):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    persons = persons[np.argsort(group_scene[persons], kind="stable")]
    scenes = group_scene[persons]
    lo = np.searchsorted(scenes, pose_scene[poses], side="left")
    hi = np.searchsorted(scenes, pose_scene[poses], side="right")
    counts = hi - lo
    pose = np.repeat(poses, counts)
    offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    person = persons[np.repeat(lo, counts) + offset]
    return pose, person
