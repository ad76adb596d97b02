"""The motion-capture field's standard metrics: PCP as on Shelf/Campus (per actor) and AP at
25–150 mm as on Panoptic. Pure numpy/scipy, no I/O. MPJPE and PA-MPJPE are in :mod:`mvm.metrics.poses`.

A limb end is a joint, or the mean of several joints (``(a, b)`` with ``a``, ``b`` tuples of
joint indices), so skeletons without a pelvis or neck joint still define the hip-to-head limb.
"""
from __future__ import annotations

import numpy as np

#: PCP limbs on the 17 COCO keypoints: the eight limbs of Shelf/Campus, the head (neck -> nose)
#: and the torso as Shelf/Campus define it, hip centre -> head bottom (the neck, i.e. the mid-shoulders).
_NECK = (5, 6)
_PELVIS = (11, 12)
COCO_PCP_LIMBS: dict[str, tuple[tuple[int, ...], tuple[int, ...]]] = {
    "left_upper_arm": ((5,), (7,)), "right_upper_arm": ((6,), (8,)),
    "left_lower_arm": ((7,), (9,)), "right_lower_arm": ((8,), (10,)),
    "left_upper_leg": ((11,), (13,)), "right_upper_leg": ((12,), (14,)),
    "left_lower_leg": ((13,), (15,)), "right_lower_leg": ((14,), (16,)),
    "head": (_NECK, (0,)),
    "torso": (_PELVIS, _NECK),
}

#: PCP limbs on the 14-joint Shelf/Campus skeleton (0 r-ankle, 1 r-knee, 2 r-hip, 3 l-hip,
#: 4 l-knee, 5 l-ankle, 6 r-wrist, 7 r-elbow, 8 r-shoulder, 9 l-shoulder, 10 l-elbow, 11 l-wrist,
#: 12 bottom head, 13 top head), as in the Shelf/Campus evaluation code.
SHELF_PCP_LIMBS: dict[str, tuple[tuple[int, ...], tuple[int, ...]]] = {
    "right_lower_leg": ((0,), (1,)), "right_upper_leg": ((1,), (2,)),
    "left_upper_leg": ((3,), (4,)), "left_lower_leg": ((4,), (5,)),
    "right_lower_arm": ((6,), (7,)), "right_upper_arm": ((7,), (8,)),
    "left_upper_arm": ((9,), (10,)), "left_lower_arm": ((10,), (11,)),
    "head": ((12,), (13,)),
    "torso": ((2, 3), (12,)),
}


def _ends(points: np.ndarray, limbs) -> tuple[np.ndarray, np.ndarray]:
    """``points: (..., J, 3)`` -> limb start and end points ``(..., L, 3)`` each."""
    start = np.stack([points[..., list(a), :].mean(-2) for a, _ in limbs.values()], -2)
    end = np.stack([points[..., list(b), :].mean(-2) for _, b in limbs.values()], -2)
    return start, end


def limbs_correct(estimate: np.ndarray, truth: np.ndarray, limbs=None, alpha: float = 0.5) -> np.ndarray:
    """Which limbs are correct: the mean of the two end-point errors is at most ``alpha`` times
    the true limb length. ``estimate, truth: (..., J, 3)`` -> ``(..., L)`` bool (False where the
    estimate lacks an end)."""
    limbs = COCO_PCP_LIMBS if limbs is None else limbs
    es, ee = _ends(np.asarray(estimate, float), limbs)
    ts, te = _ends(np.asarray(truth, float), limbs)
    with np.errstate(invalid="ignore"):
        error = 0.5 * (np.linalg.norm(es - ts, axis=-1) + np.linalg.norm(ee - te, axis=-1))
        return error <= alpha * np.linalg.norm(ts - te, axis=-1)


def _mpjpe_matrix(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``(P, J, 3)``, ``(G, J, 3)`` -> ``(P, G)`` mean joint error over joints present in both
    (inf where none)."""
    diff = np.linalg.norm(estimate[:, None] - truth[None], axis=-1)
    ok = np.isfinite(diff)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(ok, diff, 0).sum(-1) / ok.sum(-1)
    return np.where(ok.any(-1), mean, np.inf)


def pcp(estimates: list[np.ndarray], truths: list[np.ndarray], actor_ids: list[np.ndarray] | None = None,
        limbs=None, alpha: float = 0.5) -> dict:
    """Percentage of correct parts, per actor, over instants (the Shelf/Campus protocol).

    Args:
        estimates: per instant, ``(P_t, J, 3)`` estimated persons.
        truths: per instant, ``(G_t, J, 3)`` true persons (a person with no finite joint is absent).
        actor_ids: per instant, ``(G_t,)`` actor identities (default: the row index).
        limbs: the limb definition (default :data:`COCO_PCP_LIMBS`).
    Each true actor is compared with the estimate of smallest MPJPE at that instant (as the
    Shelf/Campus evaluation does); an instant without estimates counts every limb wrong. Limbs
    the truth lacks (an end joint missing) are not counted.
    Returns:
        ``{"per_actor": {id: {limb: pcp}}, "actor": {id: mean over limbs}, "average": mean over
        actors, "limbs": [names]}`` (fractions in [0, 1]).
    """
    limbs = COCO_PCP_LIMBS if limbs is None else limbs
    L = len(limbs)
    correct: dict = {}
    counts: dict = {}
    for t, (est, gt) in enumerate(zip(estimates, truths)):
        gt = np.asarray(gt, float)
        est = np.asarray(est, float).reshape(-1, *gt.shape[1:]) if len(est) else np.zeros((0,) + gt.shape[1:])
        ids = np.arange(len(gt)) if actor_ids is None else np.asarray(actor_ids[t])
        ts, te = _ends(gt, limbs)
        defined = np.isfinite(ts).all(-1) & np.isfinite(te).all(-1)                   # (G, L) limbs in the truth
        if len(est):
            nearest = np.argmin(_mpjpe_matrix(est, gt), axis=0)                       # (G,)
            ok = limbs_correct(est[nearest], gt, limbs, alpha)                      # (G, L)
        else:
            ok = np.zeros((len(gt), L), bool)
        for g in np.flatnonzero(defined.any(-1)):
            key = int(ids[g])
            correct[key] = correct.get(key, np.zeros(L)) + (ok[g] & defined[g])
            counts[key] = counts.get(key, np.zeros(L)) + defined[g]
    names = list(limbs)
    per_actor = {}
    for k in sorted(correct):
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = correct[k] / counts[k]
        per_actor[k] = {n: float(r) for n, r in zip(names, ratio) if np.isfinite(r)}
    actor = {k: float(np.mean(list(v.values()))) for k, v in per_actor.items()}
    return {"per_actor": per_actor, "actor": actor,
            "average": float(np.mean(list(actor.values()))) if actor else float("nan"), "limbs": names}


def average_precision(estimates: list[np.ndarray], scores: list[np.ndarray], truths: list[np.ndarray],
                      thresholds=(0.025, 0.05, 0.075, 0.1, 0.125, 0.15)) -> dict:
    """AP of 3D persons at MPJPE thresholds (the Panoptic protocol of VoxelPose and its followers).

    Estimates of all instants are ranked by score; each is assigned to the true person of smallest
    MPJPE at its instant; it is a true positive at threshold ``d`` when that MPJPE is below ``d``
    and that true person was not already taken by a better-ranked estimate. AP is the area under
    the interpolated precision–recall curve. Thresholds in the units of the poses (default metres).

    ``estimates``: per instant ``(P_t, J, 3)``; ``scores``: per instant ``(P_t,)``; ``truths``:
    per instant ``(G_t, J, 3)``. Returns ``{"AP@25": …, …, "recall@500": …}`` keyed in millimetres
    when the thresholds are metres.
    """
    records = []                                                                  # (score, mpjpe, instant, gt)
    total_gt = 0
    for t, (est, sc, gt) in enumerate(zip(estimates, scores, truths)):
        gt = np.asarray(gt, float)
        present = np.isfinite(gt).all(-1).any(-1)
        total_gt += int(present.sum())
        if not len(est) or not present.any():
            for s in np.asarray(sc, float).reshape(-1):
                records.append((s, np.inf, t, -1))
            continue
        cost = _mpjpe_matrix(np.asarray(est, float), gt[present])
        best = np.argmin(cost, axis=1)
        g_index = np.flatnonzero(present)[best]
        for p in range(len(est)):
            records.append((float(sc[p]), float(cost[p, best[p]]), t, int(g_index[p])))
    records.sort(key=lambda r: -r[0])
    out = {}
    for d in list(thresholds) + [0.5]:
        taken = set()
        tp = np.zeros(len(records))
        for i, (_, e, t, g) in enumerate(records):
            if g >= 0 and e < d and (t, g) not in taken:
                tp[i] = 1
                taken.add((t, g))
        ctp = np.cumsum(tp)
        recall = ctp / max(total_gt, 1)
        precision = ctp / np.arange(1, len(records) + 1)
        if d == 0.5:
            out["recall@500"] = float(recall[-1]) if len(records) else 0.0
            continue
        recall = np.concatenate([[0.0], recall, [1.0]])
        precision = np.concatenate([[0.0], precision, [0.0]])
        precision = np.maximum.accumulate(precision[::-1])[::-1]
        out[f"AP@{round(d * 1000)}"] = float(((recall[1:] - recall[:-1]) * precision[1:]).sum())
    return out
