"""Encoders: annotations of one image -> the targets of the PIF, PAF and PDF fields.

Targets use the layout of the fields (``headmeta``) with NaN meaning *no target* (zero
weight in the loss):

- ``pif: (17, 5, H, W)``: ``c`` is 1 on the cells around a joint, 0 on the background and NaN
  where a person's joint is not annotated (inside that person's box: we do not know where it
  is, so we neither reward nor punish a detection there); ``x, y`` the offset from the cell to
  the joint in cells, ``b`` a nominal spread, ``σ`` the joint's scale in cells.
- ``paf: (27, 7, H, W)``: ``c`` is 1 on cells near the segment between the two joints of a
  connection; offsets to both joints; nominal spreads.
- ``pdf: (17, 2, H, W)``: relative depth ``d`` and radius ``γ`` (the joint's scale) on the
  same cells as the PIF, NaN where the depth is unknown (2D-only data: the whole field).
- ``pdf_group: (17, H, W)``: index of the annotation each PDF cell belongs to (-1: none);
  the depth loss is scale invariant per annotation.

When cells are claimed by several people, each goes to the closest joint (PIF, PDF) or the
closest segment (PAF), so crowded scenes decode back to the same poses.
"""
from __future__ import annotations

import warnings
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from mvm.core.config import check_settings, setting
from mvm.core.keypoints import COCO_SIGMAS, NUM_JOINTS
from mvm.net.headmeta import PAF_CONNECTIONS


@dataclass(frozen=True)
class EncoderConfig:
    """Sizes of the positive regions, in field cells."""

    #: Side of the square of cells around a joint that point to it; larger: more cells vote for
    #: a joint (robust, but neighbours interfere). [cells]
    pif_side: float = setting(4.0, gt=0)
    #: Cells within this distance of a connection's segment point to its joints. [cells]
    paf_radius: float = setting(1.0, gt=0)
    #: Value written into the ``b`` channels of targets (unused by the loss, read by the decoder
    #: when it decodes targets). [cells]
    nominal_spread: float = setting(0.1, gt=0)
    #: The smallest joint scale σ of a target. [px]
    min_sigma_px: float = setting(1.0, gt=0)
    #: A person's box, grown by this much, is ignored for its missing joints. [cells]
    ignore_margin: float = setting(1.0, ge=0)

    def __post_init__(self):
        check_settings(self)


def field_shape(image_size: tuple[int, int], stride: int) -> tuple[int, int]:
    """``(width, height)`` of an image -> ``(H, W)`` cells of its fields (ceil division)."""
    w, h = image_size
    return (int(h) + stride - 1) // stride, (int(w) + stride - 1) // stride


def person_scale(keypoints: np.ndarray) -> np.ndarray:
    """Square root of the area of the box of the visible keypoints.

    ``keypoints: (N, 17, 3)`` -> ``(N,)`` pixels (0 for fewer than two visible joints).
    """
    kp = np.asarray(keypoints, dtype=float)
    vis = kp[..., 2] > 0
    big = np.where(vis[..., None], kp[..., :2], np.nan)
    with _quiet():
        lo, hi = np.nanmin(big, axis=1), np.nanmax(big, axis=1)
    wh = np.nan_to_num(hi - lo, nan=0.0)
    return np.sqrt(wh[:, 0] * wh[:, 1])


def encode(keypoints: np.ndarray, image_size: tuple[int, int], stride: int,
           depths: np.ndarray | None = None, config: EncoderConfig = EncoderConfig(),
           connections: tuple[tuple[int, int], ...] = PAF_CONNECTIONS,
           ignore_boxes: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Field targets of one image.

    Args:
        keypoints: ``(N, 17, 3)`` pixel coordinates (pixel centres at integers) and visibility
            ``v`` (> 0: annotated).
        image_size: ``(width, height)`` of the image in pixels.
        stride: pixels per cell.
        depths: ``(N, 17)`` relative depths (> 0), NaN or 0 where unknown; ``None``: no depth.
        ignore_boxes: ``(M, 4)`` pixel boxes ``x0, y0, x1, y1`` whose background is not a
            target (crowds, people without keypoints, people that were not reconstructed).
    Returns:
        ``{"pif": (17, 5, H, W), "paf": (C, 7, H, W), "pdf": (17, 2, H, W),
        "pdf_group": (17, H, W)}`` float32 targets (int64 groups), NaN where there is no target.
    """
    kp = np.asarray(keypoints, dtype=float).reshape(-1, NUM_JOINTS, 3)
    N = len(kp)
    if depths is None:
        dep = np.full((N, NUM_JOINTS), np.nan)
    else:
        dep = np.asarray(depths, dtype=float)
        if dep.shape != (N, NUM_JOINTS):
            raise ValueError(f"depths: expected shape ({N}, {NUM_JOINTS}), got {dep.shape}")
        dep = np.where(dep > 0, dep, np.nan)
    H, W = field_shape(image_size, stride)
    vis = kp[:, :, 2] > 0
    xy = kp[:, :, :2] / stride                                   # (N, 17, 2) cells
    cells = np.stack(np.meshgrid(np.arange(W), np.arange(H)), -1).reshape(-1, 2).astype(float)  # (HW, 2) x, y

    sigma = np.maximum(person_scale(kp)[:, None] * COCO_SIGMAS[None, :], config.min_sigma_px) / stride  # (N, 17)
    pif, pdf, group = _encode_pif(xy, vis, sigma, dep, cells, config)
    paf = _encode_paf(xy, vis, cells, connections, config)
    _ignore_missing(pif, paf, xy, vis, cells, connections, config)
    if ignore_boxes is not None and len(ignore_boxes):
        _ignore_boxes(pif, paf, np.asarray(ignore_boxes, dtype=float) / stride, cells)
    return {
        "pif": pif.reshape(NUM_JOINTS, 5, H, W).astype(np.float32),
        "paf": paf.reshape(len(connections), 7, H, W).astype(np.float32),
        "pdf": pdf.reshape(NUM_JOINTS, 2, H, W).astype(np.float32),
        "pdf_group": group.reshape(NUM_JOINTS, H, W),
    }


def _encode_pif(xy, vis, sigma, dep, cells, config):
    """-> pif ``(17, 5, HW)``, pdf ``(17, 2, HW)``, groups ``(17, HW)``."""
    N, HW = len(xy), len(cells)
    pif = np.full((NUM_JOINTS, 5, HW), np.nan)
    pif[:, 0] = 0.0
    pdf = np.full((NUM_JOINTS, 2, HW), np.nan)
    group = np.full((NUM_JOINTS, HW), -1, dtype=np.int64)
    if N == 0:
        return pif, pdf, group
    delta = xy.transpose(1, 0, 2)[:, :, None, :] - cells[None, None]      # (17, N, HW, 2) joint - cell
    dist = np.where(vis.T[:, :, None], np.linalg.norm(delta, axis=-1), np.inf)  # (17, N, HW)
    nearest = np.argmin(dist, axis=1)                                    # (17, HW)
    d = np.take_along_axis(delta, nearest[:, None, :, None], axis=1)[:, 0]  # (17, HW, 2)
    valid = np.take_along_axis(dist, nearest[:, None, :], axis=1)[:, 0] < np.inf
    pos = valid & (np.abs(d).max(axis=-1) < 0.5 * config.pif_side)     # (17, HW)
    j, c = np.nonzero(pos)
    n = nearest[j, c]
    pif[j, 0, c] = 1.0
    pif[j, 1, c] = d[j, c, 0]
    pif[j, 2, c] = d[j, c, 1]
    pif[j, 3, c] = config.nominal_spread
    pif[j, 4, c] = sigma[n, j]
    pdf[j, 0, c] = dep[n, j]
    has_depth = np.isfinite(dep[n, j])
    pdf[j[has_depth], 1, c[has_depth]] = sigma[n, j][has_depth]
    group[j[has_depth], c[has_depth]] = n[has_depth]
    return pif, pdf, group


def _encode_paf(xy, vis, cells, connections, config):
    """-> paf ``(C, 7, HW)``."""
    C, HW, N = len(connections), len(cells), len(xy)
    paf = np.full((C, 7, HW), np.nan)
    paf[:, 0] = 0.0
    if N == 0:
        return paf
    a_idx = np.array([a for a, _ in connections])
    b_idx = np.array([b for _, b in connections])
    A, B = xy[:, a_idx].transpose(1, 0, 2), xy[:, b_idx].transpose(1, 0, 2)  # (C, N, 2)
    ok = (vis[:, a_idx] & vis[:, b_idx]).T                                     # (C, N)
    AB = B - A
    L2 = np.maximum((AB ** 2).sum(-1), 1e-12)                                   # (C, N)
    AP = cells[None, None] - A[:, :, None]                                      # (C, N, HW, 2)
    t = np.clip((AP * AB[:, :, None]).sum(-1) / L2[:, :, None], 0.0, 1.0)
    closest = A[:, :, None] + t[..., None] * AB[:, :, None]
    dist = np.where(ok[:, :, None], np.linalg.norm(cells[None, None] - closest, axis=-1), np.inf)
    nearest = np.argmin(dist, axis=1)                                           # (C, HW)
    dmin = np.take_along_axis(dist, nearest[:, None], axis=1)[:, 0]
    k, c = np.nonzero(dmin <= config.paf_radius)
    n = nearest[k, c]
    paf[k, 0, c] = 1.0
    paf[k, 1:3, c] = A[k, n] - cells[c]
    paf[k, 3:5, c] = B[k, n] - cells[c]
    paf[k, 5:7, c] = config.nominal_spread
    return paf


def _ignore_missing(pif, paf, xy, vis, cells, connections, config):
    """Set ``c`` to NaN (no target) inside the box of a person for each joint it lacks."""
    N = len(xy)
    if N == 0:
        return
    big = np.where(vis[..., None], xy, np.nan)
    has_any = vis.sum(1) >= 2
    with _quiet():
        lo = np.nanmin(big, axis=1) - config.ignore_margin                    # (N, 2)
        hi = np.nanmax(big, axis=1) + config.ignore_margin
    inside = has_any[:, None] & np.all((cells[None] >= lo[:, None]) & (cells[None] <= hi[:, None]), axis=-1)  # (N, HW)
    missing = ~vis & has_any[:, None]                                           # (N, 17)
    ignore_j = (missing.T[:, :, None] & inside[None]).any(axis=1)               # (17, HW)
    pif[:, 0][ignore_j & (pif[:, 0] == 0)] = np.nan
    a_idx = np.array([a for a, _ in connections])
    b_idx = np.array([b for _, b in connections])
    miss_c = missing[:, a_idx] | missing[:, b_idx]                              # (N, C)
    ignore_c = (miss_c.T[:, :, None] & inside[None]).any(axis=1)                # (C, HW)
    paf[:, 0][ignore_c & (paf[:, 0] == 0)] = np.nan


def _ignore_boxes(pif, paf, boxes, cells):
    """Set the background ``c`` of PIF and PAF to NaN inside ``boxes (M, 4)`` (cells; x0, y0, x1, y1)."""
    inside = ((cells[None, :, 0] >= boxes[:, None, 0]) & (cells[None, :, 0] <= boxes[:, None, 2])
              & (cells[None, :, 1] >= boxes[:, None, 1]) & (cells[None, :, 1] <= boxes[:, None, 3])).any(0)  # (HW,)
    pif[:, 0][inside[None] & (pif[:, 0] == 0)] = np.nan
    paf[:, 0][inside[None] & (paf[:, 0] == 0)] = np.nan


@contextmanager
def _quiet():
    """Silence the all-NaN warnings of nanmin/nanmax (the NaN results are handled)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


def targets_as_fields(targets: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Targets -> fields the decoder reads: NaN confidences become 0 (other NaNs stay)."""
    out = {}
    for name in ("pif", "paf", "pdf"):
        f = targets[name].copy()
        if name in ("pif", "paf"):
            f[:, 0] = np.nan_to_num(f[:, 0], nan=0.0)
        out[name] = f
    return out
