"""Run the network on images and evaluate it on a COCO keypoints file (OKS AP and depth error)."""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch

from mvm.core.keypoints import COCO_SIGMAS
from mvm.metrics.network import coco_to_common14, match_poses_2d, oks_ap, relative_depth_error, threedpw_pa_mpjpe
from mvm.net.data import letterbox, load_image, read_annotations, to_tensor
from mvm.net.decoder import DecoderConfig, Poses, decode, depth_at, normalize_depth
from mvm.net.model import PoseNet, fields_from_raw

LOG = logging.getLogger(__name__)


@torch.no_grad()
def run_model(model: PoseNet, image: np.ndarray, input_size: int,
              decoder: DecoderConfig = DecoderConfig()) -> tuple[Poses, dict[str, np.ndarray], float]:
    """Detect the people of one image.

    ``image: (H, W, 3)`` uint8 RGB -> poses in the image's pixels, the fields of the
    letterboxed input (``{"pif": (17, 5, h, w), …}``) and the letterbox scale.
    """
    stride = model.spec.stride
    boxed, scale = letterbox(image, input_size, model.spec.backbone_stride)
    device = next(model.parameters()).device
    raw = model(to_tensor(boxed)[None].to(device))
    fields = {k: v[0].float().cpu().numpy() for k, v in fields_from_raw(raw).items()}
    poses = decode(fields, stride, decoder)
    kp = poses.keypoints.copy()
    present = kp[:, :, 2] > 0
    kp[:, :, :2] = np.where(present[..., None], (kp[:, :, :2] + 0.5) / scale - 0.5, 0.0)
    return Poses(kp, poses.depth, poses.score), fields, scale


def oks(a: np.ndarray, b: np.ndarray, area: float) -> float:
    """COCO object keypoint similarity of ``a (17, 3)`` against ground truth ``b (17, 3)``."""
    vis = b[:, 2] > 0
    if not vis.any():
        return 0.0
    d2 = ((a[:, :2] - b[:, :2]) ** 2).sum(-1)
    k2 = (2 * COCO_SIGMAS) ** 2
    e = d2 / (2 * max(area, 1.0) * k2)
    present = a[:, 2] > 0
    return float(np.where(vis & present, np.exp(-e), 0.0).sum() / vis.sum())


def evaluate_detections(annotations: str | Path, detections: str | Path) -> dict[str, float]:
    """OKS AP of a COCO results file (``[{"image_id", "keypoints", "score"}]``, read by
    :func:`mvm.io.coco_results.read_coco_results`: ``image_id`` an image id of ``annotations``,
    or a file name) on a COCO keypoints file."""
    from mvm.io.coco_dataset import read_coco_dataset
    from mvm.io.coco_results import read_coco_results, results_image_index

    truth = read_coco_dataset(annotations)
    results = read_coco_results(detections, require_score=True)
    image = results_image_index(results, detections, truth.people.image_ids, truth.people.file_names)
    dets = [{"image_id": int(truth.people.image_ids[i]), "keypoints": kp.reshape(-1).tolist(), "score": float(score)}
            for i, kp, score in zip(image, results.keypoints, results.score)]
    return oks_ap(truth.document, dets)


def missing_reasons(result: dict[str, float]) -> dict[str, str]:
    """Why each NaN metric of :func:`evaluate`'s ``result`` could not be computed: ``{name: reason}``."""
    reasons = {}
    for name, value in result.items():
        if np.isfinite(value):
            continue
        if name.startswith("depth_error") and not result.get("persons"):
            reasons[name] = "no person with depth in the validation set (2D-only data)"
        elif name in ("depth_error", "depth_error_flat_matched") and not result.get("matched"):
            reasons[name] = "no detection matched a person with depth at OKS >= 0.5"
        else:
            reasons[name] = "no joint with a depth in both prediction and ground truth"
    return reasons


def evaluate(model: PoseNet, annotations: str | Path, images: str | Path | None = None, input_size: int = 385,
             decoder: DecoderConfig = DecoderConfig(), max_images: int | None = None) -> dict[str, float]:
    """OKS AP and relative-depth errors of ``model`` on a COCO keypoints file.

    Returns ``AP``, ``AP50`` (pycocotools), ``depth_error`` (mean absolute error of
    median-normalized depths of the detections matched to ground truth at OKS ≥ 0.5),
    ``depth_error_gt2d`` (the PDF read at the ground-truth keypoints), ``depth_error_flat``
    (the error of predicting the same depth for every joint, a baseline, over the same persons
    as ``depth_error_gt2d``), ``depth_error_flat_matched`` (the flat baseline over the matched
    persons and joints of ``depth_error``), ``matched`` (how many persons were matched) and
    ``persons`` (the ground-truth persons with depth).
    """
    ann = read_annotations(annotations, images)
    was_training = model.training
    model.eval()
    detections, matched_err, matched_flat, oracle_err, flat_err = [], [], [], [], []
    n_persons = 0
    n = len(ann.paths) if max_images is None else min(max_images, len(ann.paths))
    for i in range(n):
        image = load_image(ann.paths[i])
        poses, fields, scale = run_model(model, image, input_size, decoder)
        image_id = int(ann.image_ids[i])
        for kp, score in zip(poses.keypoints, poses.score):
            detections.append({"image_id": image_id, "keypoints": kp.reshape(-1).tolist(), "score": float(score)})
        gt_kp, gt_d = ann.keypoints[i], ann.depths[i]
        has_d = np.isfinite(gt_d).sum(1) >= 2
        n_persons += int(has_d.sum())
        if not has_d.any():
            continue
        boxed = gt_kp.copy()
        boxed[:, :, :2] = (boxed[:, :, :2] + 0.5) * scale - 0.5
        oracle_err.extend(relative_depth_error(depth_at(fields, boxed, model.spec.stride, decoder), gt_d)[has_d])
        flat_err.extend(relative_depth_error(np.where(np.isfinite(gt_d), 1.0, np.nan), gt_d)[has_d])
        taken = set()
        for g in np.nonzero(has_d)[0]:
            vis = gt_kp[g, :, 2] > 0
            area = float(np.ptp(gt_kp[g, vis, 0]) * np.ptp(gt_kp[g, vis, 1]))
            scores = [oks(p, gt_kp[g], area) if k not in taken else 0.0 for k, p in enumerate(poses.keypoints)]
            if scores and max(scores) >= 0.5:
                k = int(np.argmax(scores))
                taken.add(k)
                matched_err.extend(relative_depth_error(poses.depth[k][None], gt_d[g][None]))
                flat = np.where(np.isfinite(poses.depth[k]), 1.0, np.nan)
                matched_flat.extend(relative_depth_error(flat[None], gt_d[g][None]))
    gt_doc = dict(ann.document)
    gt_doc["images"] = [im for im in ann.document["images"] if im["id"] in set(ann.image_ids[:n].tolist())]
    ap = oks_ap(gt_doc, detections)
    model.train(was_training)

    def mean(values):
        values = [v for v in values if np.isfinite(v)]
        return float(np.mean(values)) if values else float("nan")

    return {"AP": ap["AP"], "AP50": ap["AP50"], "depth_error": mean(matched_err),
            "depth_error_gt2d": mean(oracle_err), "depth_error_flat": mean(flat_err),
            "depth_error_flat_matched": mean(matched_flat),
            "matched": float(len(matched_err)), "persons": float(n_persons)}


def predict_3d(model: PoseNet, image: np.ndarray, K: np.ndarray, input_size: int,
               decoder: DecoderConfig = DecoderConfig()) -> tuple[np.ndarray, np.ndarray]:
    """People of one image: 2D joints ``(P, 17, 3)`` and camera-frame 3D joints ``(P, 17, 3)``
    (relative depths back-projected through ``K (3, 3)``, scaled by the bone lengths s*)."""
    from mvm.net.lift import calibrate, lift

    poses, _, _ = run_model(model, image, input_size, decoder)
    if len(poses) == 0:
        return np.zeros((0, 17, 3)), np.zeros((0, 17, 3))
    metric, _ = calibrate(lift(poses.keypoints, normalize_depth(poses.depth), K))
    return poses.keypoints, metric


def evaluate_3dpw(model: PoseNet, data, input_size: int = 385, decoder: DecoderConfig = DecoderConfig(),
                  min_visible: int = 7, max_images: int | None = None, progress=None) -> dict:
    """PA-MPJPE of ``model`` on 3DPW poses (the paper's Table 3 protocol).

    Each image is run once; its detections are matched to the true people by their 2D
    joints (:func:`mvm.metrics.network.match_poses_2d`); the 14 common joints of each matched
    pose are Procrustes-aligned to the truth; errors are averaged per tracked person per
    clip, then over the data set (:func:`mvm.metrics.network.threedpw_pa_mpjpe`). Subjects with
    fewer than ``min_visible`` visible joints are ignored; a true person without a matching
    detection is counted in ``missed`` (and gets no error).

    Args:
        data: :class:`mvm.net.threedpw.ThreeDPWPoses`.
        progress: optional ``progress(done, total)`` callback per image.
    Returns:
        ``{"PA_MPJPE_mm", "tracks", "poses", "missed", "ignored", "images", "per_track_mm"}``.
    """
    was_training = model.training
    model.eval()
    eligible = data.visible.sum(1) >= min_visible
    images = list(dict.fromkeys(p for p, e in zip(data.images, eligible) if e))
    if max_images is not None:
        images = images[:max_images]
    rows_of: dict = {}
    for i, (path, e) in enumerate(zip(data.images, eligible)):
        if e:
            rows_of.setdefault(path, []).append(i)
    pred = np.full((len(data), 14, 3), np.nan)
    found = np.zeros(len(data), bool)
    for n, path in enumerate(images):
        rows = np.array(rows_of[path])
        kp2d, kp3d = predict_3d(model, load_image(path), data.intrinsics[rows[0]], input_size, decoder)
        match = match_poses_2d(coco_to_common14(kp2d), data.joints2d[rows])
        hit = match >= 0
        pred[rows[hit]] = coco_to_common14(kp3d[match[hit]])
        found[rows[hit]] = True
        if progress is not None:
            progress(n + 1, len(images))
    model.train(was_training)
    used = found & eligible
    error, per_track = threedpw_pa_mpjpe(pred[used], data.joints3d[used], data.visible[used], data.clip[used],
                                         data.track[used], min_visible)
    evaluated = np.isin(np.array([str(p) for p in data.images], dtype=object), [str(p) for p in images])
    return {"PA_MPJPE_mm": 1000.0 * error, "tracks": len(per_track), "poses": int(used.sum()),
            "missed": int((evaluated & eligible & ~found).sum()), "ignored": int((evaluated & ~eligible).sum()),
            "images": len(images), "per_track_mm": {f"{c}/{t}": 1000.0 * e for (c, t), e in per_track.items()}}
