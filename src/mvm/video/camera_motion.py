"""How far the camera's image moved between frames of a video, and the frames to keep by it.

The motion is measured as structure-from-motion front ends do it, cheaply: corners
(``cv2.goodFeaturesToTrack``) of downscaled grey frames tracked from frame to frame by pyramidal
Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``) with a forward-backward check, replenished as they
die (:class:`FeatureTracks`). The motion between two frames is the median displacement of the
tracks they share, as a fraction of the image diagonal (:func:`track_motion`).

Selection (:func:`select_by_motion`) is greedy along the video, like the keyframes of a visual
SLAM front end: after a kept frame, the next sharp frame is kept once the image moved
``min_motion`` since it, once fewer than half of its tracks survive (the view is changing too
fast to wait), or once ``max_gap_s`` passed (a still camera, a frozen shot); a selection that
would keep fewer than ``min_frames`` frames is filled up evenly in time.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

#: Width of the grey frames the tracks are measured on (smaller frames keep theirs). [px]
MOTION_WIDTH = 320
#: Corners tracked at once; new ones are found when fewer than 60 % of them are left. [points]
MAX_TRACKS = 200
#: A track is lost when tracking it back lands farther than this from where it started. [px]
FORWARD_BACKWARD_PX = 1.0
#: A frame is kept when fewer than this share of the last kept frame's tracks reach it; a frame
#: where fewer than this share of the tracks of the frame before survive is a bad one. [fraction]
MIN_SURVIVING = 0.5
#: Bad frames in a row tracked past (from the last good frame) before the tracks start anew. [frames]
MAX_BAD_FRAMES = 3

_LK = {"winSize": (15, 15), "maxLevel": 3,
       "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 10, 0.03)}


def motion_grey(image: np.ndarray) -> np.ndarray:
    """The grey frame tracks are measured on: ``image (H, W[, 3])`` BGR -> ``(h, w)`` uint8, at
    most :data:`MOTION_WIDTH` wide."""
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    if grey.shape[1] <= MOTION_WIDTH:
        return np.ascontiguousarray(grey)
    height = max(int(round(grey.shape[0] * MOTION_WIDTH / grey.shape[1])), 1)
    return cv2.resize(grey, (MOTION_WIDTH, height), interpolation=cv2.INTER_AREA)


@dataclass
class FeatureTracks:
    """Corners tracked along a video, one frame after the other (:meth:`add`).

    ``ids[f]: (N_f,)`` int32, sorted, and ``points[f]: (N_f, 2)`` float32: the tracks alive in
    frame ``f`` and where they are (pixels of the grey frames); ``diagonal``: their diagonal.
    A frame that loses most tracks (a blurred or damaged one) does not end them: the next frames
    are tracked from the last good one, for up to :data:`MAX_BAD_FRAMES` frames. Memory: a few
    kB per frame, whatever the frames' size.
    """

    ids: list[np.ndarray] = field(default_factory=list)
    points: list[np.ndarray] = field(default_factory=list)
    diagonal: float = 0.0
    _reference: np.ndarray | None = None
    _reference_tracks: tuple[np.ndarray, np.ndarray] | None = None
    _bad: int = 0
    _next_id: int = 0

    def add(self, image: np.ndarray) -> None:
        """Track the corners of the last good frame into ``image: (H, W[, 3])`` BGR and store them."""
        grey = motion_grey(image)
        self.diagonal = float(np.hypot(*grey.shape))
        if self._reference is None or self._reference.shape != grey.shape:
            self._anchor(grey, np.zeros(0, np.int32), np.zeros((0, 2), np.float32))
            return
        ids, points = _follow(self._reference, grey, *self._reference_tracks)
        if len(ids) < MIN_SURVIVING * len(self._reference_tracks[0]) and self._bad < MAX_BAD_FRAMES:
            self._bad += 1                                          # keep the last good frame as the reference
            self.ids.append(ids)
            self.points.append(points)
            return
        self._anchor(grey, ids, points)

    def _anchor(self, grey: np.ndarray, ids: np.ndarray, points: np.ndarray) -> None:
        """Store ``grey``'s tracks, topped up with new corners, and make it the reference."""
        if len(points) < 0.6 * MAX_TRACKS:
            fresh = _corners(grey, points, MAX_TRACKS - len(points))
            ids = np.concatenate([ids, np.arange(self._next_id, self._next_id + len(fresh), dtype=np.int32)])
            points = np.concatenate([points, fresh])
            self._next_id += len(fresh)
        self.ids.append(ids)
        self.points.append(points)
        self._reference, self._reference_tracks, self._bad = grey, (ids, points), 0


def _follow(previous: np.ndarray, grey: np.ndarray, ids: np.ndarray, points: np.ndarray):
    """The tracks ``ids: (N,)`` at ``points: (N, 2)`` of ``previous`` found in ``grey`` (forward
    and back within :data:`FORWARD_BACKWARD_PX`, inside the frame) -> (ids, points). No track
    (a black or flat frame has no corner) follows into nothing."""
    if not len(points):
        return ids, points
    start = points.reshape(-1, 1, 2)
    ahead, found, _ = cv2.calcOpticalFlowPyrLK(previous, grey, start, None, **_LK)
    back, found_back, _ = cv2.calcOpticalFlowPyrLK(grey, previous, ahead, None, **_LK)
    ahead, back = ahead.reshape(-1, 2), back.reshape(-1, 2)
    h, w = grey.shape
    good = (found.ravel() == 1) & (found_back.ravel() == 1) \
        & (np.linalg.norm(back - points, axis=1) < FORWARD_BACKWARD_PX) \
        & (ahead[:, 0] >= 0) & (ahead[:, 0] <= w - 1) & (ahead[:, 1] >= 0) & (ahead[:, 1] <= h - 1)
    return ids[good], ahead[good].astype(np.float32)


def _corners(grey: np.ndarray, existing: np.ndarray, count: int) -> np.ndarray:
    """Up to ``count`` new corners of ``grey`` away from the ``existing: (N, 2)`` ones -> ``(M, 2)``."""
    if count <= 0:
        return np.zeros((0, 2), np.float32)
    mask = np.full(grey.shape, 255, np.uint8)
    for x, y in np.round(existing).astype(int):
        cv2.circle(mask, (int(x), int(y)), 7, 0, -1)
    found = cv2.goodFeaturesToTrack(grey, maxCorners=count, qualityLevel=0.01, minDistance=7, mask=mask,
                                    blockSize=7)
    return np.zeros((0, 2), np.float32) if found is None else found.reshape(-1, 2).astype(np.float32)


def track_motion(tracks: FeatureTracks, a: int, b: int) -> tuple[float, float]:
    """(median displacement of the tracks frames ``a`` and ``b`` share, as a fraction of the
    diagonal; the share of ``a``'s tracks that reach ``b``). No shared track: (inf, 0); no track
    in ``a`` (a black or flat frame): (NaN, 1), nothing measured, so that only ``max_gap_s``
    and ``min_frames`` keep frames."""
    if not len(tracks.ids[a]):
        return float("nan"), 1.0
    common, ia, ib = np.intersect1d(tracks.ids[a], tracks.ids[b], assume_unique=True, return_indices=True)
    surviving = len(common) / max(len(tracks.ids[a]), 1)
    if not len(common):
        return float("inf"), surviving
    shift = np.linalg.norm(tracks.points[b][ib] - tracks.points[a][ia], axis=1)
    return float(np.median(shift)) / max(tracks.diagonal, 1.0), surviving


@dataclass
class Selection:
    """Frames kept by :func:`select_by_motion`: ``kept: (K,)`` indices into the candidates,
    sorted; ``reasons[k]``: why (``first``, ``motion``, ``tracks lost``, ``max gap``,
    ``min frames``); ``motion: (K,)`` the image motion since the kept frame before (fraction of
    the diagonal; NaN for the first)."""

    kept: np.ndarray
    reasons: tuple[str, ...]
    motion: np.ndarray


def select_by_motion(tracks: FeatureTracks, usable: np.ndarray, timestamps: np.ndarray, min_motion: float,
                     max_gap_s: float, min_frames: int) -> Selection:
    """The candidate frames to keep (module docstring): ``usable: (F,)`` bool (not blurred),
    ``timestamps: (F,)`` seconds, of the frames of ``tracks``."""
    chosen: dict[int, str] = {}
    last = None
    for j in np.flatnonzero(usable):
        if last is None:
            chosen[int(j)], last = "first", int(j)
            continue
        moved, surviving = track_motion(tracks, last, int(j))
        reason = ("tracks lost" if surviving < MIN_SURVIVING else "motion" if moved >= min_motion
                  else "max gap" if timestamps[j] - timestamps[last] >= max_gap_s - 1e-9 else None)
        if reason:
            chosen[int(j)], last = reason, int(j)
    for j in _fill(np.flatnonzero(usable), np.array(sorted(chosen), dtype=np.int64), timestamps, min_frames):
        chosen[j] = "min frames"
    kept = np.array(sorted(chosen), dtype=np.int64)
    motion = np.array([np.nan] + [track_motion(tracks, int(a), int(b))[0] for a, b in zip(kept[:-1], kept[1:])])
    return Selection(kept, tuple(chosen[int(k)] for k in kept), motion[:len(kept)])


def _fill(candidates: np.ndarray, kept: np.ndarray, timestamps: np.ndarray, count: int) -> list[int]:
    """Candidates to add to ``kept`` until it holds ``count`` frames (or every candidate): each
    time the candidate nearest the middle of the longest stretch of time without a kept frame
    (the start and the end of the video bound the first and the last). ``candidates, kept:``
    sorted indices into ``timestamps: (F,)``."""
    added: list[int] = []
    kept = kept.tolist()
    if len(kept) >= min(count, len(candidates)):
        return added
    start, end = timestamps[candidates[0]], timestamps[candidates[-1]]
    while len(kept) < min(count, len(candidates)):
        marks = [start] + sorted(timestamps[kept]) + [end]
        gaps = np.diff(marks)
        k = int(np.argmax(gaps))
        free = np.setdiff1d(candidates, kept)
        middle = 0.5 * (marks[k] + marks[k + 1])
        j = int(free[np.argmin(np.abs(timestamps[free] - middle))])
        kept = sorted(kept + [j])
        added.append(j)
    return added
