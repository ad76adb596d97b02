"""Ground-truth metrics of 3D poses: matching precision/recall, persons found, MPJPE, PA-MPJPE
and the similarity (Procrustes) alignment behind it (the core's one Umeyama,
:func:`mvm.core.geometry.similarity_transform`). Pure numpy/scipy, no I/O. The paper's
proxies without ground truth (E_R, outliers, |G_k|) are in :mod:`mvm.core.quality`; the
motion-capture field's PCP and AP in :mod:`mvm.metrics.mocap_scores`."""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from mvm.core.geometry import similarity_transform

#: An estimated person is a true person found when their MPJPE is below this (the demo, the
#: benchmarks and the Panoptic evaluation alike). [m]
MATCH_DISTANCE_M = 0.5


def matching_precision_recall(groups: list[np.ndarray], true_person: np.ndarray) -> tuple[float, float]:
    """Pairwise matching precision and recall.

    ``groups``: pose indices per predicted person; ``true_person: (N,)`` the true person of
    every pose, -1 for false positives. A predicted pair is two poses in one group; it is
    correct when both belong to the same true person. Recall counts all true pairs.
    """
    true_person = np.asarray(true_person)
    label = np.full(len(true_person), -1)
    for g, members in enumerate(groups):
        label[members] = g
    K = true_person.max() + 1 if len(true_person) and true_person.max() >= 0 else 0
    G = len(groups)
    pairs = lambda n: n * (n - 1) / 2  # noqa: E731
    in_group = label >= 0
    table = np.zeros((G, K + 1))
    np.add.at(table, (label[in_group], true_person[in_group] + 1), 1)   # column 0: false poses
    predicted = pairs(table.sum(1)).sum()
    correct = pairs(table[:, 1:]).sum()
    true_pairs = pairs(np.bincount(true_person[true_person >= 0], minlength=K)).sum()
    precision = correct / predicted if predicted else 1.0
    recall = correct / true_pairs if true_pairs else 1.0
    return float(precision), float(recall)


def procrustes_align(source: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None,
                     scale: bool = True) -> np.ndarray:
    """``source: (..., J, 3)`` similarity-aligned onto ``target: (..., J, 3)`` by
    :func:`similarity_transform` over ``mask: (..., J)`` (default: the joints finite in both)
    -> ``(..., J, 3)`` (NaN where ``source`` is)."""
    source = np.asarray(source, dtype=float)
    s, R, t = similarity_transform(source, target, mask, scale)
    return s[..., None, None] * np.einsum("...ij,...kj->...ki", R, source) + t[..., None, :]


def pa_mpjpe(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Procrustes-aligned mean per-joint position error of each pose.

    ``estimate, truth: (..., J, 3)`` (NaN joints ignored) -> ``(...)`` in the unit of ``truth``,
    NaN for a pose with fewer than 3 joints finite in both.
    """
    estimate, truth = np.asarray(estimate, dtype=float), np.asarray(truth, dtype=float)
    mask = np.isfinite(estimate).all(-1) & np.isfinite(truth).all(-1)
    error = np.linalg.norm(procrustes_align(estimate, truth, mask) - truth, axis=-1)
    count = mask.sum(-1)
    return np.where(count >= 3, np.where(mask, error, 0.0).sum(-1) / np.maximum(count, 1), np.nan)


def match_persons(estimate: np.ndarray, truth: np.ndarray, max_distance: float = np.inf) -> list[tuple[int, int]]:
    """Hungarian assignment of estimated to true persons by MPJPE over common joints.
    ``estimate: (P, J, 3)``, ``truth: (G, J, 3)`` -> ``[(p, g), …]`` with MPJPE <= max_distance."""
    if len(estimate) == 0 or len(truth) == 0:
        return []
    diff = np.linalg.norm(estimate[:, None] - truth[None], axis=-1)            # (P, G, J)
    with np.errstate(invalid="ignore"):
        cost = np.nanmean(np.where(np.isfinite(diff), diff, np.nan), axis=-1)
    cost = np.where(np.isfinite(cost), cost, 1e12)
    rows, cols = linear_sum_assignment(cost)
    return [(int(r), int(c)) for r, c in zip(rows, cols) if cost[r, c] <= max_distance]


def person_errors(estimate: np.ndarray, truth: np.ndarray,
                  pairs: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """MPJPE and PA-MPJPE (in the units of the inputs) of every matched pair ``(p, g)`` with at
    least 3 joints finite in both: ``(K,)`` each."""
    if not pairs:
        return np.zeros(0), np.zeros(0)
    p, g = np.array(pairs).T
    e, t = np.asarray(estimate, dtype=float)[p], np.asarray(truth, dtype=float)[g]       # (K', J, 3)
    ok = np.isfinite(e).all(-1) & np.isfinite(t).all(-1)
    kept = ok.sum(-1) >= 3
    e, t, ok = e[kept], t[kept], ok[kept]
    distance = np.where(ok, np.linalg.norm(e - t, axis=-1), 0.0)
    return distance.sum(-1) / ok.sum(-1), pa_mpjpe(e, t)


def pose_errors(estimate: np.ndarray, truth: np.ndarray, pairs: list[tuple[int, int]]) -> dict:
    """MPJPE and PA-MPJPE (in the units of the inputs) over matched pairs, averaged per person."""
    mpjpe, pa = person_errors(estimate, truth, pairs)
    return {"mpjpe": float(np.mean(mpjpe)) if len(mpjpe) else float("nan"),
            "pa_mpjpe": float(np.mean(pa)) if len(pa) else float("nan"),
            "evaluated_persons": len(mpjpe)}
