"""Metrics of the monocular network: PA-MPJPE (3DPW protocol), 2D matching of detections, OKS AP
(pycocotools), C_var, relative depth error.

All functions take arrays and return numbers; none reads files.
"""
from __future__ import annotations

import contextlib
import io

import numpy as np

from mvm.core.geometry import dlt_terms, solve_dlt
from mvm.core.keypoints import INDEX
from mvm.metrics.poses import pa_mpjpe

#: The 14 joints common to COCO and SMPL, in this order: the 12 limb joints of COCO, the
#: neck (mid-shoulders) and the head (the nose).
COMMON14_NAMES = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist",
                  "right_wrist", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle",
                  "right_ankle", "neck", "head")
_LIMBS14 = [INDEX[n] for n in COMMON14_NAMES[:12]]


def coco_to_common14(points: np.ndarray) -> np.ndarray:
    """``points: (..., 17, D)`` -> ``(..., 14, D)`` in the order of ``COMMON14_NAMES``."""
    p = np.asarray(points, dtype=float)
    neck = 0.5 * (p[..., INDEX["left_shoulder"], :] + p[..., INDEX["right_shoulder"], :])
    return np.concatenate([p[..., _LIMBS14, :], neck[..., None, :], p[..., INDEX["nose"], None, :]], axis=-2)


def threedpw_pa_mpjpe(pred: np.ndarray, gt: np.ndarray, visible: np.ndarray, clip: np.ndarray,
                      track: np.ndarray, min_visible: int = 7) -> tuple[float, dict]:
    """PA-MPJPE in the 3DPW protocol of the paper.

    Poses with fewer than ``min_visible`` visible 2D joints (of the 14) are ignored, and so are
    predictions that lack a joint (the error is over all 14); the error of each remaining pose
    is averaged per tracked person per clip, then over the tracks (a clip with two people counts
    twice).

    Args:
        pred, gt: ``(N, 14, 3)`` in ``COMMON14_NAMES`` order (see :func:`coco_to_common14`).
        visible: ``(N, 14)`` whether each joint is visible in the image.
        clip, track: ``(N,)`` clip and person identifiers of each pose.
    Returns:
        the data set's PA-MPJPE (unit of ``gt``; NaN without any pose) and ``{(clip, track): error}``.
    """
    pred, gt = np.asarray(pred, dtype=float), np.asarray(gt, dtype=float)
    if pred.shape[1:] != (14, 3) or gt.shape != pred.shape:
        raise ValueError(f"expected pred and gt of shape (N, 14, 3), got {pred.shape} and {gt.shape}")
    keep = np.asarray(visible, bool).sum(1) >= min_visible
    complete = np.isfinite(pred[keep]).all((1, 2))
    errors = np.where(complete, pa_mpjpe(pred[keep], gt[keep]), np.nan)
    keys = list(zip(np.asarray(clip)[keep].tolist(), np.asarray(track)[keep].tolist()))
    per_track: dict = {}
    for key, e in zip(keys, errors):
        if np.isfinite(e):
            per_track.setdefault(key, []).append(e)
    per_track = {k: float(np.mean(v)) for k, v in per_track.items()}
    return (float(np.mean(list(per_track.values()))) if per_track else float("nan")), per_track


def match_poses_2d(pred: np.ndarray, gt: np.ndarray, max_distance: float = 0.5) -> np.ndarray:
    """One-to-one matching of detected to true people of an image by their 2D joints.

    The cost of a pair is the mean pixel distance over the joints visible in ``gt`` and
    present in ``pred``, divided by the diagonal of the true person's visible-joint box;
    pairs above ``max_distance`` are excluded, the others assigned by minimum total cost (Hungarian).

    Args:
        pred: ``(P, J, 3)`` x, y, confidence (≤ 0: absent); gt: ``(G, J, 3)`` x, y, visibility.
    Returns:
        ``(G,)`` index of the matched detection of each true person, -1: none.
    """
    from scipy.optimize import linear_sum_assignment

    pred, gt = np.asarray(pred, dtype=float), np.asarray(gt, dtype=float)
    out = np.full(len(gt), -1)
    if len(pred) == 0 or len(gt) == 0:
        return out
    if pred.shape[1:] != gt.shape[1:]:
        raise ValueError(f"match_poses_2d: expected (P, J, 3) and (G, J, 3), got {pred.shape} and {gt.shape}")
    both = (gt[None, :, :, 2] > 0) & (pred[:, None, :, 2] > 0)                       # (P, G, J)
    dist = np.linalg.norm(pred[:, None, :, :2] - gt[None, :, :, :2], axis=-1)
    vis = gt[..., 2] > 0
    lo = np.where(vis[..., None], gt[..., :2], np.inf).min(1)
    hi = np.where(vis[..., None], gt[..., :2], -np.inf).max(1)
    diag = np.where(vis.any(1), np.linalg.norm(hi - lo, axis=-1), np.inf)            # (G,)
    with np.errstate(invalid="ignore", divide="ignore"):
        cost = (dist * both).sum(-1) / both.sum(-1) / np.maximum(diag, 1.0)
    allowed = (both.sum(-1) > 0) & (cost < max_distance)                                # gate before assigning
    rows, cols = linear_sum_assignment(np.where(allowed, cost, 1e9))
    ok = allowed[rows, cols]
    out[cols[ok]] = rows[ok]
    return out


def oks_ap(ground_truth: dict, detections: list[dict]) -> dict[str, float]:
    """COCO keypoint AP of ``detections`` against a COCO keypoints ``ground_truth`` dict (pycocotools).

    ``detections``: ``[{"image_id", "keypoints": 51 numbers, "score"}]``. Annotations without an
    ``area`` get the area of their keypoints' box. Returns AP, AP50, AP75, APm, APl, AR (0–1).
    """
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    names = ("AP", "AP50", "AP75", "APm", "APl", "AR", "AR50", "AR75", "ARm", "ARl")
    if not detections:
        return {n: 0.0 for n in names}
    gt = {"images": ground_truth["images"], "categories": ground_truth["categories"], "annotations": []}
    for ann in ground_truth["annotations"]:
        ann = dict(ann)
        kp = np.asarray(ann["keypoints"], dtype=float).reshape(-1, 3)
        vis = kp[:, 2] > 0
        if "area" not in ann:
            ann["area"] = float(np.ptp(kp[vis, 0]) * np.ptp(kp[vis, 1])) if vis.any() else 0.0
        if "bbox" not in ann and vis.any():
            x0, y0 = kp[vis, :2].min(0)
            x1, y1 = kp[vis, :2].max(0)
            ann["bbox"] = [float(x0), float(y0), float(x1 - x0), float(y1 - y0)]
        ann.setdefault("iscrowd", 0)
        ann.setdefault("num_keypoints", int(vis.sum()))
        gt["annotations"].append(ann)
    with contextlib.redirect_stdout(io.StringIO()):
        coco = COCO()
        coco.dataset = gt
        coco.createIndex()
        dets = [{"image_id": int(d["image_id"]), "category_id": 1,
                 "keypoints": [float(v) for v in d["keypoints"]], "score": float(d["score"])} for d in detections]
        res = coco.loadRes(dets)
        ev = COCOeval(coco, res, iouType="keypoints")
        ev.params.imgIds = [im["id"] for im in ground_truth["images"]]
        ev.evaluate()
        ev.accumulate()
        ev.summarize()
    return {n: float(max(v, 0.0)) for n, v in zip(names, ev.stats)}


def c_var(projections: np.ndarray, keypoints: np.ndarray, tau: float) -> float:
    """Consistency C_var of a 2D detector over a scene (the paper's Eq. var).

    For each person and joint, the 2D keypoints of confidence ≥ ``tau`` in ``M`` views are
    triangulated pairwise; ``C_var`` is the mean over the ``M(M−1)/2`` pairs of the squared
    distance to their mean, averaged over the (person, joint) with at least three such views.

    Args:
        projections: ``(V, 3, 4)`` camera matrices.
        keypoints: ``(P, V, 17, 3)`` x, y, confidence of each person in each view (0: absent).
        tau: confidence threshold that removes outliers.
    Returns:
        C_var in squared world units (NaN when no joint has three views).
    """
    Pm = np.asarray(projections, dtype=float)
    kp = np.asarray(keypoints, dtype=float)
    if kp.ndim != 4 or kp.shape[1] != len(Pm) or kp.shape[3] != 3:
        raise ValueError(f"keypoints: expected shape (P, {len(Pm)}, J, 3), got {kp.shape}")
    ok = np.nan_to_num(kp[..., 2]) >= tau                                # (P, V, J)
    u, v = np.triu_indices(len(Pm), 1)
    pair_ok = ok[:, u] & ok[:, v]                                        # (P, pairs, J)
    p, q, j = np.nonzero(pair_ok)
    if len(p) == 0:
        return float("nan")
    terms = dlt_terms(kp[..., :2], Pm[None, :, None])                  # (10, P, V, J) per view
    X = solve_dlt(terms[:, p, u[q], j] + terms[:, p, v[q], j])            # (pairs, 3) two-view DLT
    group = p * kp.shape[2] + j
    _, inv = np.unique(group, return_inverse=True)
    G = inv.max() + 1
    count = np.bincount(inv, minlength=G).astype(float)
    mean = np.stack([np.bincount(inv, X[:, k], G) for k in range(3)], -1) / count[:, None]
    sq = ((X - mean[inv]) ** 2).sum(-1)
    var = np.bincount(inv, sq, G) / count
    views = ok.sum(1).reshape(-1)[np.unique(group)]                      # views per (person, joint)
    keep = views >= 3
    return float(var[keep].mean()) if keep.any() else float("nan")


def keypoints_per_view(keypoints: np.ndarray, view: np.ndarray, score: np.ndarray, members: list[np.ndarray],
                       n_views: int) -> np.ndarray:
    """The 2D poses grouped into each reconstructed person, laid out by view, for :func:`c_var`.

    Args:
        keypoints: ``(N, J, 3)`` the 2D poses of a scene; view: ``(N,)`` their view index;
        score: ``(N,)`` (the best-scoring pose is kept where a person has two in one view);
        members: per person, the indices into the ``N`` poses grouped into it.
    Returns:
        ``(P, V, J, 3)``; zeros where a person has no pose in a view.
    """
    kp = np.asarray(keypoints, dtype=float)
    out = np.zeros((len(members), n_views) + kp.shape[1:])
    if not members:
        return out
    person = np.concatenate([np.full(len(m), p) for p, m in enumerate(members)]).astype(int)
    pose = np.concatenate([np.asarray(m, dtype=int) for m in members])
    order = np.argsort(np.asarray(score, dtype=float)[pose], kind="stable")      # the best is written last
    out[person[order], np.asarray(view)[pose[order]]] = kp[pose[order]]
    return out


def relative_depth_error(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Mean absolute error of relative depths after normalizing both by their median.

    ``pred, gt: (N, 17)`` (NaN or ≤ 0: missing) -> ``(N,)``; the medians are taken over the
    joints present in both, so the error ignores each pose's unknown scale.
    """
    p, g = np.asarray(pred, dtype=float), np.asarray(gt, dtype=float)
    ok = np.isfinite(p) & np.isfinite(g) & (p > 0) & (g > 0)
    pn, gn = np.where(ok, p, np.nan), np.where(ok, g, np.nan)
    out = np.full(len(p), np.nan)
    rows = ok.sum(1) >= 2
    if rows.any():
        pn = pn[rows] / np.nanmedian(pn[rows], axis=1, keepdims=True)
        gn = gn[rows] / np.nanmedian(gn[rows], axis=1, keepdims=True)
        out[rows] = np.nanmean(np.abs(pn - gn), axis=1)
    return out
