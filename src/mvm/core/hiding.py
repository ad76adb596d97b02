"""People hidden behind others: the views in which a nearer person of the same scene covers most
of a person's image box. In a crowd filmed by one hand-held camera a person behind others
projects into every frame and is detected in a tenth of them; counted against the frames it is
hidden in, its support looks like that of a cluster of false poses.

Arrays: ``Q`` persons, ``F`` views, ``J`` joints. Pure numpy.
"""
from __future__ import annotations

import warnings

import numpy as np

from mvm.core.duplicates import block_pairs
from mvm.core.pose_distance import PAIRS_CHUNK, person_chunks, project_in_views


def sight(X: np.ndarray, P: np.ndarray, image_size: np.ndarray, boxes: bool = False
          ) -> tuple[np.ndarray, np.ndarray | None]:
    """``(Q, F)`` bool: the views each person is in (at least half its reconstructed joints
    project in front of the camera and inside the image), and with ``boxes`` its image box in
    each view ``(Q, F, 4)`` (u0, v0, u1, v1; else None), from one projection of the persons
    ``X: (Q, J, 3)`` into ``P: (F, 3, 4)`` (``image_size: (F, 2)``), a few persons at a time
    (:func:`mvm.core.pose_distance.person_chunks`)."""
    known = np.maximum(np.isfinite(X).all(-1).sum(-1), 1)                            # (Q,)
    inside = np.zeros((len(X), len(P)), dtype=bool)
    box = np.full((len(X), len(P), 4), np.nan) if boxes else None
    for rows in person_chunks(len(X), len(P)):
        uv, seen = project_in_views(X[rows], P)                                      # (q, F, J, 2), (q, F, J)
        with np.errstate(invalid="ignore"):
            within = seen & (uv >= 0).all(-1) & (uv < image_size[None, :, None]).all(-1)
        inside[rows] = within.sum(-1) * 2 >= known[rows, None]
        if box is not None:
            box[rows, :, :2] = np.where(seen[..., None], uv, np.inf).min(2)
            box[rows, :, 2:] = np.where(seen[..., None], uv, -np.inf).max(2)
    return inside, box


def unhidden_views(inside: np.ndarray, box: np.ndarray, X: np.ndarray, P: np.ndarray, scene: np.ndarray,
                   among: np.ndarray | None = None) -> np.ndarray:
    """``(Q,)`` the views each person is in (``inside: (Q, F)``, ``box: (Q, F, 4)``,
    :func:`sight`) where no nearer person of its scene (``scene: (Q,)``, a rig instant) hides it
    (:func:`hidden_views`; only for the persons ``among: (Q,)`` bool, the others count every view)."""
    return (inside & ~hidden_views(box, *_depths(X, P), np.asarray(scene), among)).sum(1)


#: A person is hidden in a view when a nearer person's image box covers this share of its own. [0-1]
HIDDEN_COVER = 0.8


def hidden_views(box: np.ndarray, depth: np.ndarray, extent: np.ndarray, scene: np.ndarray,
                 among: np.ndarray | None = None) -> np.ndarray:
    """``(Q, F)`` bool: the views in which a person of the same scene nearer by more than a
    person's ``extent`` covers :data:`HIDDEN_COVER` of its image box or more (a person behind
    another, whose detector finds few of its joints, if any; a copy of a person, triangulated
    from a few of its poses, is not hidden by it). ``box: (Q, F, 4)`` each person's box (u0, v0,
    u1, v1; not finite: not in front of that camera), ``depth: (Q, F)`` its distance along each
    camera's axis, ``extent: (Q,)``, ``scene: (Q,)``; ``among: (Q,)`` bool, the persons to
    test (None: all; the others are never hidden). Cost linear in the views: the pairs of
    persons of one scene, a few MB of them at a time.

    >>> box = np.array([[[0, 0, 10, 20.]], [[2, 2, 9, 18.]], [[20, 0, 30, 20.]], [[1, 1, 9, 19.]]])
    >>> depth, extent = np.array([[3.0], [5.0], [1.0], [3.2]]), np.full(4, 0.5)
    >>> hidden_views(box, depth, extent, np.zeros(4, dtype=int))[:, 0].tolist()
    [False, True, False, False]
    """
    Q, F = depth.shape
    hidden = np.zeros((Q, F), dtype=bool)
    step = max(1, 8 * PAIRS_CHUNK // max(F, 1))                                 # boxes of 4 MB
    chosen = None if among is None else np.asarray(among)
    for q, r in block_pairs(np.asarray(scene), step):                           # a person's pairs together
        if chosen is not None:
            q, r = q[chosen[q]], r[chosen[q]]
        if not len(q):
            continue
        a, b = box[q], box[r]                                                   # (k, F, 4)
        with np.errstate(invalid="ignore"):
            width = np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0])
            height = np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1])
            area = (a[..., 2] - a[..., 0]) * (a[..., 3] - a[..., 1])
            covered = (np.clip(width, 0, None) * np.clip(height, 0, None) >= HIDDEN_COVER * area) & (area > 0) \
                & (depth[r] + extent[q, None] < depth[q])                      # (k, F)
        first = np.flatnonzero(np.r_[True, q[1:] != q[:-1]])                     # runs of one person
        hidden[q[first]] |= np.logical_or.reduceat(covered, first, axis=0)
    return hidden


def _depths(X: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(Q, F)`` the distance of each person's centroid along the axis of each camera
    ``P: (F, 3, 4)``, and ``(Q,)`` the person's extent, the root mean square distance of its
    joints to that centroid (NaN: no joint)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        centroid = np.nanmean(X, axis=1)                                         # (Q, 3)
        extent = np.sqrt(np.nanmean(((X - centroid[:, None]) ** 2).sum(-1), axis=1))
    return centroid @ P[:, 2, :3].T + P[:, 2, 3], extent

