"""What the report shows, computed from arrays: person labels of the 2D poses, reprojections,
per-joint errors, the comparison with ground truth and the 3D view's frame. Pure numpy, no I/O.

Axes: ``V`` views, ``N`` 2D poses, ``P`` persons, ``G`` true persons, ``J = 17`` joints.
"""
from __future__ import annotations

import colorsys

import numpy as np

from mvm.core.geometry import project
from mvm.core.keypoints import NUM_JOINTS
from mvm.metrics.poses import match_persons, matching_precision_recall, pa_mpjpe, pose_errors

#: Colour of 2D poses that belong to no person (RGB).
UNMATCHED_RGB = (150, 150, 150)


def person_colors(P: int) -> np.ndarray:
    """``P`` distinct, saturated colours: ``(P, 3)`` uint8 RGB (golden-ratio hues)."""
    hues = (0.08 + 0.618033988749895 * np.arange(P)) % 1.0
    rgb = [colorsys.hsv_to_rgb(h, 0.8 if i % 2 == 0 else 0.6, 0.98) for i, h in enumerate(hues)]
    return np.round(255 * np.array(rgb, dtype=float).reshape(P, 3)).astype(np.uint8)


def hex_color(rgb) -> str:
    """``(3,)`` RGB ints -> ``"#rrggbb"``."""
    return "#" + "".join(f"{int(c):02x}" for c in rgb)


def pose_labels(n_poses: int, members: list[np.ndarray]) -> np.ndarray:
    """The person of every 2D pose: ``(N,)`` int, -1 for unmatched poses.

    ``members``: ``P`` arrays of pose indices (a pose in two persons keeps the first)."""
    labels = np.full(n_poses, -1, dtype=np.int64)
    for p in range(len(members) - 1, -1, -1):
        index = np.asarray(members[p], dtype=np.int64)
        if len(index) and (index.min() < 0 or index.max() >= n_poses):
            raise ValueError(f"members[{p}]: pose index out of range [0, {n_poses})")
        labels[index] = p
    return labels


def reproject(X: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project every person into every view.

    ``X: (P, J, 3)`` (NaN: missing), ``P: (V, 3, 4)`` -> pixels ``(V, P, J, 2)`` and
    ``ok: (V, P, J)`` (finite and in front of the camera)."""
    X = np.asarray(X, dtype=float)
    if X.ndim != 3 or X.shape[-1] != 3:
        raise ValueError(f"X: expected shape (P, J, 3), got {X.shape}")
    uv, depth = project(X[None], np.asarray(P, dtype=float)[:, None])
    ok = np.isfinite(uv).all(-1) & (depth > 0)
    return uv, ok


def member_errors(X: np.ndarray, labels: np.ndarray, keypoints: np.ndarray, view: np.ndarray,
                  P: np.ndarray) -> np.ndarray:
    """Reprojection error of every matched 2D keypoint: ``(N, J)`` px, NaN where the pose is
    unmatched, the keypoint missing (v = 0) or the 3D joint not reconstructed.

    ``X: (P, J, 3)``, ``labels: (N,)``, ``keypoints: (N, J, 3)``, ``view: (N,)``, ``P: (V, 3, 4)``."""
    N = len(labels)
    errors = np.full((N, NUM_JOINTS), np.nan)
    matched = labels >= 0
    if not matched.any():
        return errors
    uv, depth = project(X[labels[matched]], P[view[matched]])          # (M, J, 2)
    e = np.linalg.norm(uv - keypoints[matched, :, :2], axis=-1)
    e[~((keypoints[matched, :, 2] > 0) & np.isfinite(e) & (depth > 0))] = np.nan
    errors[matched] = e
    return errors


def joint_error_summary(errors: np.ndarray) -> dict:
    """Per-joint median, 90th percentile and count of ``errors: (N, J)`` (NaN ignored):
    each ``(J,)`` (NaN where a joint has no error)."""
    count = np.isfinite(errors).sum(0)
    median = np.full(errors.shape[1], np.nan)
    p90 = np.full(errors.shape[1], np.nan)
    has = count > 0
    if has.any():
        median[has] = np.nanmedian(errors[:, has], axis=0)
        p90[has] = np.nanpercentile(errors[:, has], 90, axis=0)
    return {"median": median, "p90": p90, "count": count}


def compare_with_truth(X: np.ndarray, members: list[np.ndarray], truth: np.ndarray,
                       true_person: np.ndarray, max_distance: float) -> dict:
    """Estimate against ground truth (lengths in the units of the inputs).

    Args:
        X: ``(P, J, 3)`` estimated persons; members: their pose indices.
        truth: ``(G, J, 3)`` true persons; true_person: ``(N,)`` the true person of every
            2D pose (-1: a false positive).
        max_distance: an estimate matches a true person when their MPJPE is below this.
    Returns:
        ``pairs`` [(p, g)], ``truth_of`` ``(P,)`` (-1: no match), per-person ``mpjpe`` and
        ``pa_mpjpe`` ``(P,)`` (NaN: no match), per-joint error ``joint_error`` ``(J,)``,
        ``mpjpe``, ``pa_mpjpe``, ``precision``, ``recall``, ``found``, ``true``.
    """
    X = np.asarray(X, dtype=float)
    truth = np.asarray(truth, dtype=float)
    pairs = match_persons(X, truth, max_distance)
    Pn = len(X)
    truth_of = np.full(Pn, -1)
    mpjpe = np.full(Pn, np.nan)
    pa = np.full(Pn, np.nan)
    per_joint = np.full((len(pairs), NUM_JOINTS), np.nan)
    for i, (p, g) in enumerate(pairs):
        truth_of[p] = g
        d = np.linalg.norm(X[p] - truth[g], axis=-1)
        per_joint[i] = d
        ok = np.isfinite(d)
        if ok.sum() >= 3:
            mpjpe[p] = d[ok].mean()
            pa[p] = pa_mpjpe(X[p], truth[g])
    precision, recall = matching_precision_recall(members, np.asarray(true_person))
    overall = pose_errors(X, truth, pairs)
    with np.errstate(invalid="ignore"):
        joint_error = (np.nanmean(per_joint, axis=0) if len(pairs) and np.isfinite(per_joint).any()
                       else np.full(NUM_JOINTS, np.nan))
    return {"pairs": pairs, "truth_of": truth_of, "person_mpjpe": mpjpe, "person_pa_mpjpe": pa,
            "joint_error": joint_error, "mpjpe": overall["mpjpe"], "pa_mpjpe": overall["pa_mpjpe"],
            "precision": precision, "recall": recall, "found": len(pairs), "true": len(truth)}


def up_direction(R: np.ndarray, min_spread: float = 0.1) -> np.ndarray:
    """The world's up direction as the cameras see it. ``R: (V, 3, 3)`` world -> camera ->
    ``(3,)`` unit vector.

    Hand-held cameras and rigs keep their x axes (image rows) about horizontal, so up is the
    normal of the plane the x axes span, signed like the cameras' mean ``-y`` axis. When the
    x axes barely differ (second singular value below ``min_spread`` of the first, e.g. a
    straight dolly) the mean ``-y`` axis itself is returned.
    """
    R = np.asarray(R, dtype=float)
    down = -R[:, 1, :].sum(0)
    norm = np.linalg.norm(down)
    fallback = down / norm if norm > 1e-9 else np.array([0.0, 0.0, 1.0])
    _, s, vt = np.linalg.svd(R[:, 0, :], full_matrices=False)
    if len(s) < 2 or s[1] < min_spread * s[0]:
        return fallback
    normal = vt[-1] if len(s) == 3 else np.cross(vt[0], vt[1])
    normal /= np.linalg.norm(normal)
    return normal if normal @ fallback >= 0 else -normal


def display_frame(up: np.ndarray, center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A rotation ``(3, 3)`` and origin ``(3,)`` taking world points to a frame with ``up``
    along +z and ``center`` at the origin: ``x_display = M @ (x - origin)``."""
    up = np.asarray(up, dtype=float)
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, up)
    x /= np.linalg.norm(x)
    y = np.cross(up, x)
    return np.stack([x, y, up]), np.asarray(center, dtype=float)


def frustums(K: np.ndarray, R: np.ndarray, t: np.ndarray, size: np.ndarray, depth: float) -> np.ndarray:
    """Camera pyramids in the world: ``(V, 5, 3)`` centre then the image corners at ``depth``
    (top-left, top-right, bottom-right, bottom-left). ``K, R: (V, 3, 3)``, ``t: (V, 3)``,
    ``size: (V, 2)``."""
    V = len(K)
    w, h = size[:, 0], size[:, 1]
    zero = np.zeros(V)
    corners = np.stack([np.stack([zero, zero], 1), np.stack([w, zero], 1),
                        np.stack([w, h], 1), np.stack([zero, h], 1)], axis=1)     # (V, 4, 2)
    homogeneous = np.concatenate([corners, np.ones((V, 4, 1))], axis=2)
    rays = np.einsum("vij,vcj->vci", np.linalg.inv(K), homogeneous)              # camera frame, z = 1
    centers = -np.einsum("vji,vj->vi", R, t)
    world = np.einsum("vji,vcj->vci", R, depth * rays) + centers[:, None]
    return np.concatenate([centers[:, None], world], axis=1)


def sample_views(V: int, count: int) -> np.ndarray:
    """``min(V, count)`` evenly spaced view indices, first and last included: ``(k,)``."""
    if V <= 0 or count <= 0:
        return np.zeros(0, dtype=np.int64)
    return np.unique(np.round(np.linspace(0, V - 1, min(V, count))).astype(np.int64))
