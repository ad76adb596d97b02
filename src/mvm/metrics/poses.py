"""Ground-truth metrics: matching precision/recall, persons found, MPJPE, PA-MPJPE. Pure
numpy/scipy, no I/O. The paper's proxies without ground truth (E_R, outliers, |G_k|) are in
:mod:`mvm.core.quality`; the motion-capture field's PCP and AP in :mod:`mvm.eval.mocap`."""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

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


def similarity_transform(source: np.ndarray, target: np.ndarray, scale: bool = True
                         ) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``target ≈ s R source + t`` (Umeyama). ``source, target: (N, 3)``
    -> ``s``, ``R: (3, 3)``, ``t: (3,)`` (``s = 1`` without ``scale``)."""
    mu_a, mu_b = source.mean(0), target.mean(0)
    A0, B0 = source - mu_a, target - mu_b
    U, S, Vt = np.linalg.svd(B0.T @ A0)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = (S * np.diag(D)).sum() / (A0**2).sum() if scale else 1.0
    return s, R, mu_b - s * R @ mu_a


def procrustes_align(source: np.ndarray, target: np.ndarray, scale: bool = True) -> np.ndarray:
    """Similarity-align ``source: (J, 3)`` to ``target: (J, 3)`` over joints finite in both;
    returns the aligned source ``(J, 3)``."""
    ok = np.isfinite(source).all(-1) & np.isfinite(target).all(-1)
    s, R, t = similarity_transform(source[ok], target[ok], scale)
    return s * source @ R.T + t


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


def person_errors(estimate: np.ndarray, truth: np.ndarray, pairs: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """MPJPE and PA-MPJPE (in the units of the inputs) of every matched pair ``(p, g)`` with at
    least 3 joints finite in both: ``(K,)`` each."""
    mpjpe, pa = [], []
    for p, g in pairs:
        e, t = estimate[p], truth[g]
        ok = np.isfinite(e).all(-1) & np.isfinite(t).all(-1)
        if ok.sum() < 3:
            continue
        mpjpe.append(np.linalg.norm(e[ok] - t[ok], axis=-1).mean())
        aligned = procrustes_align(e, t)
        pa.append(np.linalg.norm(aligned[ok] - t[ok], axis=-1).mean())
    return np.array(mpjpe, dtype=float), np.array(pa, dtype=float)


def pose_errors(estimate: np.ndarray, truth: np.ndarray, pairs: list[tuple[int, int]]) -> dict:
    """MPJPE and PA-MPJPE (in the units of the inputs) over matched pairs, averaged per person."""
    mpjpe, pa = person_errors(estimate, truth, pairs)
    return {"mpjpe": float(np.mean(mpjpe)) if len(mpjpe) else float("nan"),
            "pa_mpjpe": float(np.mean(pa)) if len(pa) else float("nan"),
            "evaluated_persons": len(mpjpe)}
