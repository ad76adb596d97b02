"""Overlays: the 2D poses of a frame in the colour of their person (unmatched in grey) and the
reprojected 3D poses over them, on the frame or on a neutral background of the image size.

``draw_overlay`` only draws (arrays in, image out); ``render_view`` and ``write_overlays``
read frames and write images or an MP4.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.core.camera import distort, has_lens
from mvm.core.keypoints import COCO_SKELETON
from mvm.errors import InputError
from mvm.io.files import atomic_output, atomic_write_bytes
from mvm.io.images import read_image
from mvm.io.layout import DEFAULT_OUTPUT, OVERLAY
from mvm.io.outputs import atomic_replace_dir, check_output_location
from mvm.io.scene_dir import output_dir, scene_inputs
from mvm.report.analysis import UNMATCHED_RGB, person_colors, pose_labels, reproject
from mvm.report.load import SceneResult, load_result

log = logging.getLogger(__name__)

#: Background of views without a frame image (BGR): a dark neutral grey.
NEUTRAL_BGR = (48, 48, 48)
#: Image suffixes ``write_overlays`` writes one file per frame for.
IMAGE_SUFFIXES = (".png", ".jpg")
_SKELETON = np.array(COCO_SKELETON)


def opencv():
    """The ``cv2`` module; its absence is one :class:`InputError` line saying how to install it."""
    try:
        import cv2
    except ImportError:  # pragma: no cover - opencv is a core dependency
        raise InputError(None, None, "overlays need OpenCV: pip install opencv-python-headless") from None
    return cv2


def _bgr(rgb) -> tuple[int, int, int]:
    return int(rgb[2]), int(rgb[1]), int(rgb[0])


def _lighten(rgb, amount: float = 0.55) -> np.ndarray:
    return np.asarray(rgb, dtype=float) * (1 - amount) + 255 * amount


def draw_overlay(image: np.ndarray, keypoints: np.ndarray, labels: np.ndarray, colors: np.ndarray,
                 reprojected: np.ndarray | None = None, reprojected_ok: np.ndarray | None = None,
                 scale: float = 1.0) -> np.ndarray:
    """Draw one view's poses on a copy of ``image``.

    Args:
        image: ``(H, W, 3)`` uint8 BGR.
        keypoints: ``(n, 17, 3)`` the view's 2D poses (x, y in pixels of the full image, v).
        labels: ``(n,)`` person of each pose (-1: unmatched, drawn grey).
        colors: ``(P, 3)`` uint8 RGB of the persons.
        reprojected: ``(P, 17, 2)`` the 3D poses projected into the view (pixels), or None;
            reprojected_ok: ``(P, 17)`` which of them to draw.
        scale: factor from full-image pixels to ``image`` pixels.
    Returns:
        ``(H, W, 3)`` uint8 BGR: thick lines and dots for the 2D poses, thin light lines and
        rings for the reprojected 3D poses.
    """
    cv2 = opencv()
    image = np.ascontiguousarray(image, dtype=np.uint8).copy()
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image: expected shape (H, W, 3), got {image.shape}")
    keypoints = np.asarray(keypoints, dtype=float).reshape(-1, 17, 3)
    labels = np.asarray(labels).reshape(-1)
    if len(labels) != len(keypoints):
        raise ValueError(f"labels: expected {len(keypoints)} entries, got {len(labels)}")
    H, W = image.shape[:2]
    thick = max(2, int(round(max(H, W) / 400)))
    shift = 4                                     # sub-pixel precision of cv2 drawing
    fixed = lambda xy: tuple(int(round(c * scale * (1 << shift))) for c in xy)  # noqa: E731
    # unmatched first, so that persons are drawn over them
    for i in np.argsort(labels >= 0, kind="stable"):
        color = _bgr(UNMATCHED_RGB if labels[i] < 0 else colors[labels[i]])
        kp, ok = keypoints[i, :, :2], keypoints[i, :, 2] > 0
        for a, b in _SKELETON:
            if ok[a] and ok[b]:
                cv2.line(image, fixed(kp[a]), fixed(kp[b]), color, thick, cv2.LINE_AA, shift)
        for j in np.flatnonzero(ok):
            cv2.circle(image, fixed(kp[j]), (thick + 1) << shift, color, -1, cv2.LINE_AA, shift)
    if reprojected is not None:
        reprojected = np.asarray(reprojected, dtype=float)
        ok_all = np.isfinite(reprojected).all(-1) if reprojected_ok is None else reprojected_ok
        limit = 4 * max(H, W) / max(scale, 1e-9)
        for p in range(len(reprojected)):
            color = _bgr(_lighten(colors[p]))
            uv = reprojected[p]
            ok = ok_all[p] & (np.abs(uv) < limit).all(-1)
            for a, b in _SKELETON:
                if ok[a] and ok[b]:
                    cv2.line(image, fixed(uv[a]), fixed(uv[b]), color, 1, cv2.LINE_AA, shift)
            for j in np.flatnonzero(ok):
                cv2.circle(image, fixed(uv[j]), (thick + 1) << shift, color, 1, cv2.LINE_AA, shift)
    return image


class ViewRenderer:
    """Draws the overlay of any view of a reconstructed scene (reads the frame image when the
    scene has ``frames/``, else draws on a neutral background of the image size)."""

    def __init__(self, result: SceneResult):
        self.result = result
        scene = result.scene
        self.labels = pose_labels(len(scene.poses), result.persons.members)
        self.colors = person_colors(len(result.persons))
        self.reprojected, self.reprojected_ok = reproject(result.persons.keypoints3d, scene.cameras.P)
        self.frames_dir = result.frames_dir
        self.missing_frames = 0

    @property
    def has_frames(self) -> bool:
        return self.frames_dir is not None

    def _background(self, v: int) -> tuple[np.ndarray, bool]:
        cv2 = opencv()
        W, H = (int(round(s)) for s in self.result.scene.cameras.size[v])
        if self.frames_dir is not None:
            path = self.frames_dir / self.result.scene.cameras.names[v]
            try:
                image = read_image(path, root=self.result.path)
            except InputError as e:
                image, problem = None, e.problem
            else:
                problem = ""
            if image is not None:
                if image.shape[:2] != (H, W):
                    image = cv2.resize(image, (W, H), interpolation=cv2.INTER_AREA)
                return image, True
            self.missing_frames += 1
            log.warning("%s: %s; drawing on a neutral background", path, problem)
        return np.full((H, W, 3), NEUTRAL_BGR, dtype=np.uint8), False

    def render(self, v: int, max_width: int | None = None) -> np.ndarray:
        """The overlay of view ``v``: ``(H, W, 3)`` uint8 BGR, at most ``max_width`` wide."""
        cv2 = opencv()
        image, real = self._background(v)
        H, W = image.shape[:2]
        scale = 1.0
        if max_width and W > max_width:
            scale = max_width / W
            image = cv2.resize(image, (max_width, max(1, int(round(H * scale)))), interpolation=cv2.INTER_AREA)
        poses = self.result.scene.poses
        rows = np.flatnonzero(poses.view == v)
        keypoints = poses.keypoints[rows].copy()
        uv = self.reprojected[v]
        cams = self.result.scene.cameras
        if real and has_lens(cams.distortion[v], cams.fisheye[v]):            # drawn on the frame as shot
            keypoints[:, :, :2] = distort(keypoints[:, :, :2], cams.K[v], cams.distortion[v], bool(cams.fisheye[v]))
            uv = distort(uv, cams.K[v], cams.distortion[v], bool(cams.fisheye[v]))
        return draw_overlay(image, keypoints, self.labels[rows], self.colors, uv,
                            self.reprojected_ok[v] & np.isfinite(uv).all(-1), scale)


@dataclass
class OverlaySummary:
    """What ``write_overlays`` wrote: ``path`` (a folder or a video), ``frames`` written,
    ``on_frames`` whether the scene's images were the background."""

    path: Path
    frames: int
    on_frames: bool


def write_overlays(scene_dir: str | Path, out: str | Path | None = None, output: str = DEFAULT_OUTPUT,
                   step: int = 1, max_width: int | None = None, fps: float = 10.0,
                   image_format: str = ".jpg") -> OverlaySummary:
    """Draw the overlay of every ``step``-th view of a reconstructed scene.

    Args:
        scene_dir: the scene directory (with ``<output>/poses3d.json``).
        out: a ``.mp4`` path (a video) or a folder (one image per view, named as the view);
            default ``<scene_dir>/<output>/overlay/``.
        step: draw every ``step``-th view; max_width: downscale wider views to this width.
        fps: frame rate of a video; image_format: ``.jpg`` or ``.png`` for a folder.
    """
    if step < 1:
        raise InputError(None, "--every", f"expected a positive step, got {step}")
    if image_format not in IMAGE_SUFFIXES:
        raise InputError(None, "image format", f"expected one of {IMAGE_SUFFIXES}, got {image_format!r}")
    out = Path(out) if out is not None else output_dir(scene_dir, output) / OVERLAY
    video = out.suffix.lower() == ".mp4"
    check_output_location(out, scene_inputs(scene_dir, output), replaced=not video)
    result = load_result(scene_dir, output)
    renderer = ViewRenderer(result)
    views = range(0, len(result.scene.cameras), step)
    if video:
        write_video(out, (renderer.render(v, max_width) for v in views), fps)
    else:
        atomic_replace_dir(lambda tmp: _write_images(tmp, renderer, views, max_width, image_format), out)
    log.info("%s: %d overlays written", out, len(views))
    return OverlaySummary(out, len(views), renderer.has_frames)


def _write_images(folder: Path, renderer: ViewRenderer, views, max_width: int | None, image_format: str) -> None:
    """One overlay image per view of ``views`` into ``folder``, named as the view."""
    cv2 = opencv()
    for v in views:
        ok, data = cv2.imencode(image_format, renderer.render(v, max_width))
        if not ok:
            raise InputError(folder, None, f"cannot encode view {v} as {image_format}")
        name = Path(renderer.result.scene.cameras.names[v]).with_suffix(image_format)
        atomic_write_bytes(folder / name, data.tobytes())


def write_video(path: Path, images, fps: float) -> None:
    """Write BGR images (resized to the first one's size) as an MP4, atomically."""
    cv2 = opencv()
    writer = None
    with atomic_output(path, suffix=".mp4") as tmp:
        try:
            for image in images:
                if writer is None:
                    size = (image.shape[1], image.shape[0])
                    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
                    if not writer.isOpened():
                        raise InputError(path, None, "OpenCV cannot write MP4 video here (no mp4v encoder)")
                if (image.shape[1], image.shape[0]) != size:
                    image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
                writer.write(image)
            if writer is None:
                raise InputError(path, None, "no views to write")
        finally:
            if writer is not None:
                writer.release()
