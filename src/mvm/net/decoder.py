"""Decoder: fields of one image -> poses with a relative depth per keypoint.

1. *Seeds*: every PIF cell with confidence above ``pif_threshold`` votes for the point it
   regresses; the high-resolution confidence at a point is the sum of the votes' Gaussians
   (``σ`` of each cell), normalized by the number of cells that vote for one joint. Seeds are
   the local maxima of that confidence (non-maximum suppression within ``nms_radius``).
2. *Association*: starting from the best unused seed, a pose grows greedily along the PAF:
   for a known joint, the PAF cell whose regressed end point lies closest to it (weighted by
   its confidence and spread) gives the position of the connected joint, snapped to the
   nearest unused seed of that joint. The most confident connection is always taken first.
3. *Depth*: at each keypoint the PDF is read as ``D = Σ d_ij N(x | p_ij, γ_ij) / Σ N(…)`` over
   the cells of that joint (``p_ij`` the point the PIF cell regresses), the normalized form
   of the paper's depth map.

Everything here is numpy on one image; the loops run over seeds and connections of one pose,
never over pairs of poses.
"""
from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

from mvm.core.config import check_settings, setting
from mvm.core.keypoints import NUM_JOINTS
from mvm.net.headmeta import PAF_CONNECTIONS


@dataclass(frozen=True)
class DecoderConfig:
    """Thresholds of the decoder (confidences in [0, 1], distances in field cells)."""

    #: PIF cells below this confidence do not vote; lower is slower, with more recall. [0-1]
    pif_threshold: float = setting(0.1, ge=0, le=1)
    #: A seed needs this high-resolution confidence to start a pose; lower finds more poses. [0-1]
    seed_threshold: float = setting(0.2, ge=0, le=1)
    #: PAF cells below this confidence are not used for association. [0-1]
    paf_threshold: float = setting(0.1, ge=0, le=1)
    #: Joints scoring below this are dropped from a pose. [0-1]
    keypoint_threshold: float = setting(0.1, ge=0, le=1)
    #: Poses whose mean keypoint score (over 17) is below this are dropped. [0-1]
    instance_threshold: float = setting(0.1, ge=0, le=1)
    #: Poses with fewer joints are dropped. [joints]
    min_keypoints: int = setting(3, ge=0, le=17)
    #: Seeds of one joint closer than their scale σ are merged, within
    #: ``[min_nms_radius, nms_radius]``; larger merges more. [cells]
    nms_radius: float = setting(0.5, ge=0)
    #: The smallest merging radius of seeds (see ``nms_radius``). [cells]
    min_nms_radius: float = setting(0.25, ge=0)
    #: A pose whose joints lie, for at least this fraction, on the same joints of a better pose
    #: (within ``dedup_radius``) is dropped; lower drops more. [0-1]
    dedup_fraction: float = setting(0.5, ge=0, le=1)
    #: Distance within which two poses' joints count as the same (see ``dedup_fraction``). [cells]
    dedup_radius: float = setting(0.75, ge=0)
    #: A joint found through the PAF snaps to a seed within this distance. [cells]
    snap_radius: float = setting(1.5, ge=0)
    #: Lower bound of the regression spread ``b`` used in association. [cells]
    min_spread: float = setting(0.1, gt=0)
    #: How many PIF cells vote for one joint (the encoder's ``pif_side²``); normalizes the
    #: high-resolution confidence. [cells]
    votes_per_joint: float = setting(16.0, gt=0)
    #: At most this many poses per image. [poses]
    max_poses: int = setting(100, ge=1)

    def __post_init__(self):
        check_settings(self)


@dataclass(frozen=True)
class Poses:
    """Decoded poses of one image.

    Attributes:
        keypoints: ``(P, 17, 3)`` x, y in pixels and a score in [0, 1] (0: missing joint).
        depth: ``(P, 17)`` relative depth as read from the PDF (NaN where missing); its scale
            is arbitrary per pose, see :meth:`relative_depth`.
        score: ``(P,)`` pose scores, decreasing.
    """

    keypoints: np.ndarray
    depth: np.ndarray
    score: np.ndarray

    def __len__(self) -> int:
        return len(self.keypoints)

    def relative_depth(self) -> np.ndarray:
        """Depths divided by each pose's median depth over its joints: ``(P, 17)``."""
        return normalize_depth(self.depth)


def normalize_depth(depth: np.ndarray) -> np.ndarray:
    """``depth: (..., 17)`` -> the same divided by the median over finite entries (NaN kept)."""
    d = np.asarray(depth, dtype=float)
    d = np.where(np.isfinite(d) & (d > 0), d, np.nan)
    out = np.full_like(d, np.nan)
    ok = np.isfinite(d).any(axis=-1)
    out[ok] = d[ok] / np.nanmedian(d[ok], axis=-1, keepdims=True)
    return out


def decode(fields: dict[str, np.ndarray], stride: int, config: DecoderConfig = DecoderConfig(),
           connections: tuple[tuple[int, int], ...] = PAF_CONNECTIONS) -> Poses:
    """Decode the fields of one image.

    Args:
        fields: ``{"pif": (17, 5, H, W), "paf": (C, 7, H, W), "pdf": (17, 2, H, W) or absent}``
            activated field values (see :func:`mvm.net.model.fields_from_raw`).
        stride: pixels per cell.
    Returns:
        :class:`Poses` in pixels.
    """
    pif, paf = np.asarray(fields["pif"], dtype=float), np.asarray(fields["paf"], dtype=float)
    pdf = fields.get("pdf")
    if pif.ndim != 4 or pif.shape[:2] != (NUM_JOINTS, 5):
        raise ValueError(f"pif: expected shape (17, 5, H, W), got {pif.shape}")
    if paf.shape[:2] != (len(connections), 7) or paf.shape[2:] != pif.shape[2:]:
        raise ValueError(f"paf: expected shape ({len(connections)}, 7, {pif.shape[2]}, {pif.shape[3]}), "
                         f"got {paf.shape}")
    votes = [_votes(pif[j], config.pif_threshold) for j in range(NUM_JOINTS)]
    seeds = [_seeds(v, config) for v in votes]
    links = [_links(paf[k], config.paf_threshold) for k in range(len(connections))]
    adjacency = [[] for _ in range(NUM_JOINTS)]
    for k, (a, b) in enumerate(connections):
        adjacency[a].append((k, True, b))
        adjacency[b].append((k, False, a))

    order = sorted(((s["score"][i], j, i) for j, s in enumerate(seeds) for i in range(len(s["score"]))
                    if s["score"][i] >= config.seed_threshold), reverse=True)
    poses = []
    for _score, j, i in order:
        if seeds[j]["used"][i]:
            continue
        pose = _grow(j, i, seeds, links, adjacency, config)
        _suppress(pose, seeds)
        kp_score = pose[:, 2]
        if (kp_score > 0).sum() < config.min_keypoints or kp_score.sum() / NUM_JOINTS < config.instance_threshold:
            continue
        if _duplicate(pose, poses, config):
            continue
        poses.append(pose)
        if len(poses) >= config.max_poses:
            break
    kp = np.array(poses, dtype=float).reshape(-1, NUM_JOINTS, 3)
    depth = _read_depth(kp, votes, pdf) if pdf is not None else np.full(kp.shape[:2], np.nan)
    score = kp[:, :, 2].sum(axis=1) / NUM_JOINTS
    rank = np.argsort(-score, kind="stable")
    kp, depth, score = kp[rank], depth[rank], score[rank]
    kp[:, :, :2] *= stride
    kp[kp[:, :, 2] == 0, :2] = 0.0
    return Poses(kp, depth, score)


def depth_at(fields: dict[str, np.ndarray], keypoints: np.ndarray, stride: int,
             config: DecoderConfig = DecoderConfig()) -> np.ndarray:
    """Read the PDF at given keypoints (e.g. ground truth). ``keypoints: (N, 17, 3)`` pixels -> ``(N, 17)``.

    Every cell votes here (weighted by its confidence), so a depth is read even where the
    PIF is not confident.
    """
    pif = np.asarray(fields["pif"], dtype=float)
    votes = [_votes(pif[j], -1.0) for j in range(NUM_JOINTS)]
    kp = np.asarray(keypoints, dtype=float).copy()
    kp[..., :2] /= stride
    return _read_depth(kp, votes, fields["pdf"])


def _votes(pif_j: np.ndarray, threshold: float) -> dict[str, np.ndarray]:
    """``pif_j: (5, H, W)`` -> the voting cells: points ``(M, 2)`` in cells, ``c``, ``σ``, flat index.

    Cells vote when their confidence exceeds ``threshold``; a negative threshold takes all cells.
    """
    _, H, W = pif_j.shape
    c = pif_j[0].reshape(-1)
    selected = np.isfinite(c) if threshold < 0 else np.nan_to_num(c) > threshold
    idx = np.nonzero(selected)[0]
    gx, gy = idx % W, idx // W
    p = np.stack([gx + pif_j[1].reshape(-1)[idx], gy + pif_j[2].reshape(-1)[idx]], axis=-1)
    sigma = np.nan_to_num(pif_j[4].reshape(-1)[idx], nan=0.5)
    ok = np.isfinite(p).all(axis=1)
    return {"p": p[ok], "c": c[idx][ok], "sigma": np.maximum(sigma[ok], 0.1), "index": idx[ok]}


def _seeds(v: dict[str, np.ndarray], config: DecoderConfig) -> dict[str, np.ndarray]:
    """Non-maximum-suppressed peaks of the high-resolution confidence of one joint.

    -> points ``p (S, 2)``, ``score (S,)``, suppression ``radius (S,)`` in cells, ``used (S,)``.
    """
    p, c, s = v["p"], v["c"], v["sigma"]
    if len(p) == 0:
        return {"p": np.zeros((0, 2)), "score": np.zeros(0), "radius": np.zeros(0), "used": np.zeros(0, bool)}
    d2 = ((p[:, None] - p[None]) ** 2).sum(-1)                           # (M, M)
    g = c[None] * np.exp(-0.5 * d2 / s[None] ** 2)
    hr = np.minimum(1.0, g.sum(1) / config.votes_per_joint)
    radius = np.clip(s, config.min_nms_radius, config.nms_radius)
    near_all = d2 < radius[:, None] ** 2
    suppressed = np.zeros(len(p), bool)
    keep, pos = [], []
    for i in np.argsort(-hr, kind="stable"):
        if suppressed[i]:
            continue
        near = near_all[i] & ~suppressed
        w = g[i, near]
        pos.append((w[:, None] * p[near]).sum(0) / w.sum())
        keep.append(i)
        suppressed |= near_all[i]
    return {"p": np.array(pos).reshape(-1, 2), "score": hr[keep], "radius": radius[keep],
            "used": np.zeros(len(keep), bool)}


def _links(paf_k: np.ndarray, threshold: float) -> dict[str, np.ndarray]:
    """``paf_k: (7, H, W)`` -> confident cells: end points ``e1, e2 (M, 2)``, ``c``, ``b1``, ``b2``."""
    _, H, W = paf_k.shape
    c = paf_k[0].reshape(-1)
    idx = np.nonzero(np.nan_to_num(c) > threshold)[0]
    g = np.stack([idx % W, idx // W], axis=-1).astype(float)
    f = paf_k.reshape(7, -1)[:, idx]
    out = {"c": c[idx], "e1": g + f[1:3].T, "e2": g + f[3:5].T, "b1": f[5], "b2": f[6]}
    ok = np.isfinite(out["e1"]).all(1) & np.isfinite(out["e2"]).all(1)
    return {k: val[ok] for k, val in out.items()}


def _connect(link, forward: bool, x: np.ndarray, config: DecoderConfig):
    """Best end point of a connection from a known joint at ``x (2,)`` -> (point, score) or None."""
    if len(link["c"]) == 0:
        return None
    src, dst, b = (link["e1"], link["e2"], link["b1"]) if forward else (link["e2"], link["e1"], link["b2"])
    spread = np.maximum(np.nan_to_num(b, nan=config.min_spread), config.min_spread)
    s = link["c"] * np.exp(-0.5 * ((src - x) ** 2).sum(-1) / spread ** 2)
    i = int(np.argmax(s))
    return dst[i], float(s[i])


def _snap(seeds_j, point: np.ndarray, config: DecoderConfig) -> int:
    """Index of the nearest unused seed within ``snap_radius`` of ``point``, or -1."""
    if len(seeds_j["score"]) == 0:
        return -1
    d2 = ((seeds_j["p"] - point) ** 2).sum(-1)
    d2[seeds_j["used"]] = np.inf
    i = int(np.argmin(d2))
    return i if d2[i] <= config.snap_radius ** 2 else -1


def _candidate(j_from, j_to, k, forward, pose, seeds, links, config):
    """Heap entry for reaching joint ``j_to`` from ``j_from`` through connection ``k``, or None."""
    found = _connect(links[k], forward, pose[j_from, :2], config)
    if found is None:
        return None
    point, s = found
    i = _snap(seeds[j_to], point, config)
    if i >= 0:
        score = float(np.sqrt(s * seeds[j_to]["score"][i]))
        point = seeds[j_to]["p"][i]
    else:
        score = 0.5 * s
    if score < config.keypoint_threshold:
        return None
    return (-score, j_to, i, j_from, k, forward, float(point[0]), float(point[1]))


def _grow(j0: int, i0: int, seeds, links, adjacency, config) -> np.ndarray:
    """Greedy growth of one pose from seed ``i0`` of joint ``j0`` -> ``(17, 3)`` in cells."""
    pose = np.zeros((NUM_JOINTS, 3))
    pose[j0] = (*seeds[j0]["p"][i0], seeds[j0]["score"][i0])
    seeds[j0]["used"][i0] = True
    heap = []

    def push(entry):
        if entry is not None:
            heapq.heappush(heap, entry)

    def push_from(j):
        for k, forward, j_to in adjacency[j]:
            if pose[j_to, 2] == 0:
                push(_candidate(j, j_to, k, forward, pose, seeds, links, config))

    push_from(j0)
    while heap:
        neg, j, i, j_from, k, forward, x, y = heapq.heappop(heap)
        if pose[j, 2] > 0:
            continue
        if i >= 0 and seeds[j]["used"][i]:  # the seed was taken meanwhile: look again
            push(_candidate(j_from, j, k, forward, pose, seeds, links, config))
            continue
        pose[j] = (x, y, -neg)
        if i >= 0:
            seeds[j]["used"][i] = True
        push_from(j)
    return pose


def _suppress(pose: np.ndarray, seeds) -> None:
    """Mark the seeds that lie within their NMS radius of the pose's joint as used."""
    for j in np.nonzero(pose[:, 2] > 0)[0]:
        s = seeds[j]
        if len(s["score"]):
            s["used"] |= ((s["p"] - pose[j, :2]) ** 2).sum(-1) < s["radius"] ** 2


def _duplicate(pose: np.ndarray, kept: list[np.ndarray], config: DecoderConfig) -> bool:
    """Whether most joints of ``pose (17, 3)`` coincide with the same joints of a kept pose."""
    if not kept:
        return False
    others = np.array(kept)                                                # (Q, 17, 3)
    have = (pose[None, :, 2] > 0) & (others[:, :, 2] > 0)
    close = have & (((others[:, :, :2] - pose[None, :, :2]) ** 2).sum(-1) < config.dedup_radius ** 2)
    n = max(int((pose[:, 2] > 0).sum()), 1)
    return bool((close.sum(1) >= config.dedup_fraction * n).any())


def _read_depth(kp: np.ndarray, votes, pdf: np.ndarray) -> np.ndarray:
    """Relative depth at every decoded keypoint. ``kp: (P, 17, 3)`` in cells -> ``(P, 17)``.

    The Gaussian of each cell is narrowed to at most a third of the distance between the
    keypoint and the nearest same joint of another pose, and a cell is read only for the
    keypoint its regressed position is nearest to, so neighbours (at other depths) do not blend.
    """
    pdf = np.asarray(pdf, dtype=float)
    depth = np.full(kp.shape[:2], np.nan)
    for j in range(NUM_JOINTS):
        v = votes[j]
        have = np.nonzero(kp[:, j, 2] > 0)[0]
        if len(have) == 0 or len(v["p"]) == 0:
            continue
        d = pdf[j, 0].reshape(-1)[v["index"]]
        gamma = pdf[j, 1].reshape(-1)[v["index"]]
        ok = np.isfinite(d) & np.isfinite(gamma) & (d > 0)
        if not ok.any():
            continue
        p, c, d, gamma = v["p"][ok], v["c"][ok], d[ok], np.maximum(gamma[ok], 0.05)
        x = kp[have, j, :2]                                              # (P_j, 2)
        gap = np.sqrt(((x[:, None] - x[None]) ** 2).sum(-1) + np.diag(np.full(len(x), np.inf)))
        width = np.minimum(gamma[None], gap.min(axis=1, keepdims=True) / 3)  # (P_j, M)
        d2 = ((x[:, None] - p[None]) ** 2).sum(-1)                      # (P_j, M)
        logw = np.log(c)[None] - 0.5 * d2 / np.maximum(width, 1e-3) ** 2
        own = d2 <= d2.min(axis=0, keepdims=True)                       # each vote reads for its nearest keypoint
        own[~own.any(axis=1)] = True                                     # a keypoint without votes of its own: all
        logw = np.where(own, logw, -np.inf)
        w = np.exp(logw - logw.max(axis=1, keepdims=True))
        depth[have, j] = (w * d[None]).sum(1) / w.sum(1)
    return depth
