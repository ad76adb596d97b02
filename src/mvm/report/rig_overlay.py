"""Overlays of a rig: each camera's video (``RIG_DIR/videos/<camera>.<ext>``) with the 2D poses of
every frame in the colour of the track they were matched to (unmatched in grey) and every track's
3D pose projected through the camera's lens, one video per camera.

A camera's frame ``f`` is the reference camera's frame ``f + offset`` (``sync.toml``): the
persons drawn on it are those of that instant. The videos' frame numbers are their frames'
positions from 0, as the pose files number them; a video of another size than the calibration's
image is drawn on at its own scale.
"""
from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mvm.core.camera import distort, project_camera
from mvm.core.completion import MISSING
from mvm.core.config import DEFAULT_FRAME_RATE_HZ
from mvm.errors import InputError
from mvm.io.images import step_frames
from mvm.io.layout import OVERLAY, VIDEOS
from mvm.io.outputs import add_to_output_set, atomic_replace_dir, check_output_location
from mvm.report.analysis import person_colors
from mvm.report.overlay import draw_overlay, opencv, write_video
from mvm.report.rig_load import RigReportData, in_output_set

log = logging.getLogger(__name__)


@dataclass
class RigOverlaySummary:
    """What :func:`write_rig_overlays` wrote: ``folder``, ``videos`` (camera -> (path, frames
    drawn)) and ``skipped``: the cameras without a video."""

    folder: Path
    videos: dict = field(default_factory=dict)
    skipped: list = field(default_factory=list)


class CameraDrawer:
    """Draws the poses of one camera of a reconstructed rig on its video frames (no I/O)."""

    def __init__(self, data: RigReportData, v: int):
        p, cams, det = data.poses, data.calibration.cameras, data.detections
        lens = data.calibration.distortions[v]
        fisheye = bool(data.calibration.fisheye[v])
        tracks, rank = np.unique(p.track, return_inverse=True)
        self.colors = person_colors(len(tracks))
        self.K = len(tracks)
        self.rank = rank
        self.frames = p.frames
        self.shift = int((data.offsets or {}).get(data.names[v], 0))
        self.size = cams.size[v]
        uv, depth = project_camera(p.X, cams.K[v], cams.R[v], cams.t[v], lens, fisheye)          # (Q, J, 2)
        self.uv = uv
        self.ok = np.isfinite(uv).all(-1) & (depth > 0) & (p.flags != MISSING)
        self.person_bounds = np.searchsorted(p.instant, np.arange(len(p.frames) + 1))
        rows = np.flatnonzero((det.view == v) & (det.instant >= 0))
        rows = rows[np.argsort(det.instant[rows], kind="stable")]
        self.rows = rows
        self.row_bounds = np.searchsorted(det.instant[rows], np.arange(len(p.frames) + 1))
        kp = det.keypoints[rows].copy()
        kp[..., :2] = distort(np.where(kp[..., 2:] > 0, kp[..., :2], np.nan), cams.K[v], lens, fisheye)
        kp[..., :2] = np.nan_to_num(kp[..., :2])
        self.keypoints = kp
        label = np.full(len(det), -1, dtype=np.int64)
        matched = data.detection[:, v] >= 0
        label[data.detection[matched, v]] = rank[matched]
        self.labels = label[rows]

    def instant_of(self, frame: int) -> int:
        """The instant of the camera's frame ``frame`` (its position in the video), -1 if none."""
        t = int(np.searchsorted(self.frames, frame + self.shift))
        return t if t < len(self.frames) and self.frames[t] == frame + self.shift else -1

    def draw(self, image: np.ndarray, frame: int, max_width: int | None = None) -> np.ndarray:
        """The overlay of the camera's frame ``frame`` on ``image: (H, W, 3)`` BGR."""
        cv2 = opencv()
        H, W = image.shape[:2]
        scale = W / float(self.size[0])
        if max_width and W > max_width:
            image = cv2.resize(image, (max_width, max(1, round(H * max_width / W))), interpolation=cv2.INTER_AREA)
            scale *= max_width / W
        t = self.instant_of(frame)
        if t < 0:
            return np.ascontiguousarray(image)
        rows = slice(self.row_bounds[t], self.row_bounds[t + 1])
        persons = slice(self.person_bounds[t], self.person_bounds[t + 1])
        reprojected = np.full((self.K, 17, 2), np.nan)
        ok = np.zeros((self.K, 17), bool)
        reprojected[self.rank[persons]] = self.uv[persons]
        ok[self.rank[persons]] = self.ok[persons]
        return draw_overlay(image, self.keypoints[rows], self.labels[rows], self.colors, reprojected, ok, scale)


#: A video's frames may differ from the calibration's image in shape by this much. [1]
MAX_ASPECT_CHANGE = 0.01


def _open(path: Path, size: np.ndarray):
    """An opened ``cv2.VideoCapture`` of ``path`` that has decoded its first frame, rewound. A
    video that does not decode, or whose frames are not the shape of the calibration's image
    ``size: (2,)`` (width, height), is one :class:`InputError` line."""
    cv2 = opencv()
    capture = cv2.VideoCapture(str(path))
    ok, image = capture.read() if capture.isOpened() else (False, None)
    if not ok:
        capture.release()
        raise InputError(path, None, "cannot be decoded: OpenCV read no frame from it (not a video, or cut short)")
    H, W = image.shape[:2]
    if abs((W / H) / (size[0] / size[1]) - 1) > MAX_ASPECT_CHANGE:
        capture.release()
        raise InputError(path, None, f"frames of {W}×{H} px, but the calibration's images of this camera are "
                                     f"{size[0]:g}×{size[1]:g}: another camera's video, or cropped?")
    capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
    return capture


def _frames(capture, drawer: CameraDrawer, step: int, max_width: int | None, counter: list) -> Iterator[np.ndarray]:
    """The overlays of every ``step``-th frame of ``capture`` (released at the end); the frames
    in between are grabbed, not decoded."""
    try:
        for frame, image in step_frames(capture, lambda n: n % step == 0):
            counter[0] += 1
            yield drawer.draw(image, frame, max_width)
    finally:
        capture.release()


def rig_overlay_target(out_dir: Path, out: str | Path | None, step: int) -> Path:
    """The folder the overlays of the rig's output set ``out_dir`` go to: ``out``, default
    ``out_dir/overlay``; refused before any work when it names a video or ``step`` is not positive."""
    if step < 1:
        raise InputError(None, "--every", f"expected a positive step, got {step}")
    target = Path(out) if out is not None else out_dir / OVERLAY
    if target.suffix.lower() == ".mp4":
        raise InputError(None, "-o", f"{target} names a video, but a rig's overlays are one video per camera: "
                                     "give a folder")
    return target


def write_rig_overlays(data: RigReportData, videos: dict[str, Path], inputs: list[Path], out: str | Path | None = None,
                       step: int = 1, max_width: int | None = None) -> RigOverlaySummary:
    """Write ``<out>/<camera>.mp4`` for every camera of a reconstructed rig, ``data``
    (:func:`mvm.stages.view.load_rig_view`), that has a video in ``videos`` (camera -> video;
    ``out`` defaults to ``RIG_DIR/<output>/overlay``, listed in the output set). Cameras without
    a video are skipped and named in the summary; a video that does not decode is refused, and
    an ``out`` that is, holds or lies inside one of ``inputs``, before anything is written. The
    folder is written whole (:func:`mvm.io.outputs.atomic_replace_dir`)."""
    out_dir = data.out_dir
    target = rig_overlay_target(out_dir, out, step)
    check_output_location(target, inputs)
    if not videos:
        raise InputError(data.rig_dir / VIDEOS, None, "no video of any camera: expected videos/<camera>.<ext> "
                                                      f"for the cameras {', '.join(data.names)}")
    captures = {}
    try:
        for name, path in videos.items():
            captures[name] = _open(path, data.calibration.cameras.size[data.names.index(name)])
    except InputError:
        for c in captures.values():
            c.release()
        raise
    summary = RigOverlaySummary(target, skipped=[n for n in data.names if n not in videos])

    def build(folder: Path) -> None:
        for name, capture in captures.items():
            fps = capture.get(opencv().CAP_PROP_FPS)
            counter = [0]
            path = folder / f"{name}.mp4"
            write_video(path, _frames(capture, CameraDrawer(data, data.names.index(name)), step, max_width, counter),
                         fps if 0 < fps < 1000 else DEFAULT_FRAME_RATE_HZ)
            summary.videos[name] = (target / path.name, counter[0])

    try:
        if in_output_set(target, out_dir):
            add_to_output_set(out_dir, target.name, lambda p: atomic_replace_dir(build, p))
        else:
            atomic_replace_dir(build, target)
    finally:
        for c in captures.values():
            c.release()
    log.info("%s: overlays of %d cameras", target, len(summary.videos))
    return summary

