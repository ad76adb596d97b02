"""Appearance descriptors of 2D poses (paper Sec. 4.3.1: S is a cosine similarity).

Two sources, same contract (one non-negative vector per pose, compared by cosine):

- :func:`colour_descriptor` — from the frame itself: hue–saturation histograms of the torso,
  arms and legs, sampled along the pose's limbs. Hue and saturation do not change when the
  light gets brighter or darker (a multiplicative change of R, G, B), so the descriptor is
  robust to exposure drift along a video. Histograms are square-rooted, so that the cosine
  of two descriptors is the Bhattacharyya coefficient of their colour distributions.
- :func:`pool_features` — from a network's feature map: features averaged along the limbs.
"""
from __future__ import annotations

import warnings

import cv2
import numpy as np

#: Limb segments sampled for the colour descriptor: (joint a, joint b, half-width as a
#: fraction of the torso length, region). A joint index of -1 / -2 is the mid-shoulder /
#: mid-hip point. Regions: 0 torso, 1 arms, 2 legs.
_SEGMENTS = np.array([
    (-1, -2, 0.30, 0),
    (5, 7, 0.08, 1), (6, 8, 0.08, 1), (7, 9, 0.06, 1), (8, 10, 0.06, 1),
    (11, 13, 0.10, 2), (12, 14, 0.10, 2), (13, 15, 0.08, 2), (14, 16, 0.08, 2),
])
REGIONS = 3
HUE_BINS = 12
SAT_BINS = 3
#: Pixels with saturation or value below these (0–255) count as achromatic (one bin).
MIN_SATURATION = 40
MIN_VALUE = 40
BINS = HUE_BINS * SAT_BINS + 1
DIM = REGIONS * BINS
_ALONG = np.linspace(0.1, 0.9, 8)
_ACROSS = np.linspace(-1.0, 1.0, 5)


def _extended_joints(xy: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Append mid-shoulder (index 17) and mid-hip (18): ``xy: (N, 17, 2)``, ``ok: (N, 17)`` ->
    ``(N, 19, 2)``, ``(N, 19)``."""
    mid_sh = 0.5 * (xy[:, 5] + xy[:, 6])
    mid_hip = 0.5 * (xy[:, 11] + xy[:, 12])
    xy = np.concatenate([xy, mid_sh[:, None], mid_hip[:, None]], axis=1)
    ok = np.concatenate([ok, (ok[:, 5] & ok[:, 6])[:, None], (ok[:, 11] & ok[:, 12])[:, None]], axis=1)
    return xy, ok


def limb_samples(keypoints: np.ndarray, threshold: float = 0.2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample points on the limbs of every pose.

    ``keypoints: (N, 17, 3)`` -> ``points: (N, L, M, 2)`` pixels, ``valid: (N, L)`` and
    ``region: (L,)`` with ``L`` the limb segments and ``M`` samples per segment.
    """
    kp = np.asarray(keypoints, dtype=float)
    xy, ok = _extended_joints(kp[..., :2], kp[..., 2] >= threshold)
    a = np.where(_SEGMENTS[:, 0] < 0, 17 + (_SEGMENTS[:, 0] == -2), _SEGMENTS[:, 0]).astype(int)
    b = np.where(_SEGMENTS[:, 1] < 0, 17 + (_SEGMENTS[:, 1] == -2), _SEGMENTS[:, 1]).astype(int)
    A, B = xy[:, a], xy[:, b]                                              # (N, L, 2)
    torso = np.linalg.norm(xy[:, 17] - xy[:, 18], axis=-1)                 # (N,)
    box = np.where(ok[..., None], xy, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # all-NaN rows: poses without joints
        height = np.nanmax(box[..., 1], axis=1) - np.nanmin(box[..., 1], axis=1)
    scale = np.where(ok[:, 17] & ok[:, 18] & (torso > 1), torso, np.nan_to_num(height / 3, nan=0.0))
    d = B - A
    length = np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
    normal = np.stack([-d[..., 1], d[..., 0]], axis=-1) / length
    half = _SEGMENTS[:, 2][None, :, None] * scale[:, None, None]           # (N, L, 1)
    along = A[:, :, None, None] + _ALONG[None, None, :, None, None] * d[:, :, None, None]
    across = (_ACROSS[None, None, None, :, None] * half[..., None, None]) * normal[:, :, None, None]
    points = (along + across).reshape(len(kp), len(_SEGMENTS), -1, 2)
    valid = ok[:, a] & ok[:, b] & (scale[:, None] > 2)
    return points, valid, _SEGMENTS[:, 3].astype(int)


def hs_bins(hsv: np.ndarray) -> np.ndarray:
    """Histogram bin of HSV pixels (OpenCV ranges: H 0–179, S, V 0–255). ``(..., 3)`` -> ``(...)``
    in ``[0, BINS)``; the last bin is achromatic (dark or grey)."""
    h, s, v = hsv[..., 0].astype(int), hsv[..., 1].astype(int), hsv[..., 2].astype(int)
    hue = np.minimum(h * HUE_BINS // 180, HUE_BINS - 1)
    sat = np.minimum((s - MIN_SATURATION) * SAT_BINS // (256 - MIN_SATURATION), SAT_BINS - 1)
    chromatic = (s >= MIN_SATURATION) & (v >= MIN_VALUE)
    return np.where(chromatic, hue * SAT_BINS + np.maximum(sat, 0), BINS - 1)


def colour_descriptor(image: np.ndarray, keypoints: np.ndarray, threshold: float = 0.2) -> np.ndarray:
    """Colour descriptors of the poses of one frame.

    ``image: (H, W, 3)`` uint8 BGR, ``keypoints: (N, 17, 3)`` pixels -> ``(N, DIM)``
    non-negative, unit length (all zero for a pose with no measurable limb).
    """
    kp = np.asarray(keypoints, dtype=float).reshape(-1, 17, 3)
    N = len(kp)
    if N == 0:
        return np.zeros((0, DIM))
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image: expected shape (H, W, 3), got {image.shape}")
    H, W = image.shape[:2]
    hsv = cv2.cvtColor(cv2.GaussianBlur(image, (3, 3), 0), cv2.COLOR_BGR2HSV)
    points, valid, region = limb_samples(kp, threshold)                   # (N, L, M, 2)
    x = np.round(points[..., 0]).astype(int)
    y = np.round(points[..., 1]).astype(int)
    inside = (x >= 0) & (x < W) & (y >= 0) & (y < H) & valid[..., None]
    bins = hs_bins(hsv[np.clip(y, 0, H - 1), np.clip(x, 0, W - 1)])     # (N, L, M)
    flat = (np.arange(N)[:, None, None] * REGIONS + region[None, :, None]) * BINS + bins
    hist = np.bincount(flat[inside], minlength=N * REGIONS * BINS).reshape(N, REGIONS, BINS).astype(float)
    total = hist.sum(-1, keepdims=True)
    hist = np.sqrt(np.where(total > 0, hist / np.maximum(total, 1), 0.0)).reshape(N, DIM)
    norm = np.linalg.norm(hist, axis=1, keepdims=True)
    return np.where(norm > 0, hist / np.maximum(norm, 1e-12), 0.0)


def pool_features(features: np.ndarray, keypoints: np.ndarray, stride: float,
                  threshold: float = 0.2, samples: int = 5) -> np.ndarray:
    """Average a network's feature map along each pose's bones (the paper's appearance).

    ``features: (C, h, w)`` at ``stride`` pixels per cell, ``keypoints: (N, 17, 3)`` pixels of
    the network input -> ``(N, C)`` unit length (zero when no bone is visible).
    """
    from mvm.core.keypoints import BONES

    features = np.asarray(features, dtype=float)
    C, h, w = features.shape
    kp = np.asarray(keypoints, dtype=float).reshape(-1, 17, 3)
    bones = np.array(BONES)
    ok = kp[..., 2] >= threshold
    a, b = kp[:, bones[:, 0], :2], kp[:, bones[:, 1], :2]                 # (N, B, 2)
    t = np.linspace(0.0, 1.0, samples)[None, None, :, None]
    pts = (a[:, :, None] + t * (b - a)[:, :, None]) / stride               # (N, B, S, 2) cells
    x = np.clip(np.round(pts[..., 0] - 0.5).astype(int), 0, w - 1)
    y = np.clip(np.round(pts[..., 1] - 0.5).astype(int), 0, h - 1)
    use = (ok[:, bones[:, 0]] & ok[:, bones[:, 1]])[..., None] & np.ones(samples, dtype=bool)
    values = features[:, y, x]                                            # (C, N, B, S)
    weight = use.astype(float)
    pooled = (values * weight[None]).sum((2, 3)).T / np.maximum(weight.sum((1, 2)), 1)[:, None]
    norm = np.linalg.norm(pooled, axis=1, keepdims=True)
    return np.where(norm > 0, pooled / np.maximum(norm, 1e-12), 0.0)
