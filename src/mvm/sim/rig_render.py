"""Rendered videos of a simulated rig capture (:mod:`mvm.sim.rig_scene`): what each camera films.

Every camera films the mannequins of :mod:`mvm.sim.mannequin_video` (capsules and a head,
drawn far to near) moving with the capture's real motion, in a room of muted noise textures,
through its own lens (the radial distortion of the calibration) and with its frame offset:
camera ``c``'s frame ``f`` shows the instant ``f + offsets[c]``, as the simulated detections
do. The room is rendered once per camera (the cameras do not move), at most 640 pixels wide.

The people wear a marker on every joint, as in marker-based motion capture: a small disc whose
colour codes the person and the joint (:func:`marker_colours`: blue 255, green for the joint,
red for the person), drawn without anti-aliasing over the person's own body (as a detector
infers the joints a body hides of itself; the nose and eyes of a person facing away are left
out) and hidden by other people nearer. No other
pixel of the videos has a blue of 255 (room and clothes are muted, the skin's blue is 220), so
a lossless video (``.mkv``, FFV1) lets a detector find each visible joint exactly from the
pixels; an ``.mp4`` (MPEG-4 part 2) blurs the codes, as any lossy video would.
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from mvm.core.camera import distort, undistort
from mvm.core.keypoints import NUM_JOINTS
from mvm.sim.mannequin_video import RenderConfig, draw_figures, noise_texture, render_room

#: Video file type -> OpenCV's four-character codec: MPEG-4 part 2, or FFV1 (lossless).
CODECS = {".mp4": "mp4v", ".mkv": "FFV1", ".avi": "FFV1"}
#: Marker colour codes (BGR): blue, green of joint j = base + step * j, red of person g likewise.
MARKER_BLUE = 255
MARKER_BASE = 20
MARKER_JOINT_STEP = 12
MARKER_PERSON_STEP = 7
#: Clothes and room stay in this range of each channel (muted: never a marker's blue). [0-255]
MUTED = (70.0, 180.0)


def marker_colours(people: int) -> np.ndarray:
    """``(G, 17, 3)`` uint8 BGR: the marker colour of every joint of every person (all distinct)."""
    if people * MARKER_PERSON_STEP + MARKER_BASE > 255:
        raise ValueError(f"at most {(255 - MARKER_BASE) // MARKER_PERSON_STEP} people wear distinct markers")
    g, j = np.meshgrid(np.arange(people), np.arange(NUM_JOINTS), indexing="ij")
    return np.stack([np.full_like(g, MARKER_BLUE), MARKER_BASE + MARKER_JOINT_STEP * j,
                     MARKER_BASE + MARKER_PERSON_STEP * g], -1).astype(np.uint8)


def _lens_maps(K: np.ndarray, distortion: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """The remap of a pinhole image into the camera's distorted image: for every distorted pixel,
    where the pinhole image has it (``cv2.remap`` maps, ``(H, W)`` float32 each); None without a lens."""
    if distortion is None or not np.any(distortion):
        return None
    w, h = size
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    xy = undistort(np.stack([u, v], -1).reshape(-1, 2), K, distortion).reshape(h, w, 2)
    return xy[..., 0].astype(np.float32), xy[..., 1].astype(np.float32)


#: The room is rendered at most this wide, then enlarged (its textures are smooth). [px]
ROOM_WIDTH = 640


def _room(K: np.ndarray, R: np.ndarray, center: np.ndarray, distortion: np.ndarray, size: tuple[int, int],
          textures: list[np.ndarray]) -> np.ndarray:
    """The room seen by one camera through its lens: ``(H, W, 3)`` uint8 BGR, ray-cast at most
    :data:`ROOM_WIDTH` wide (the intrinsics scaled), distorted, then enlarged to ``size``."""
    scale = max(1, int(np.ceil(size[0] / ROOM_WIDTH)))
    small = (int(np.ceil(size[0] / scale)), int(np.ceil(size[1] / scale)))
    Ks = K.copy()
    Ks[:2, :2] /= scale
    Ks[:2, 2] = (K[:2, 2] + 0.5) / scale - 0.5
    room = render_room(Ks, R, center, small, textures, RenderConfig())
    maps = _lens_maps(Ks, distortion, small)
    if maps is not None:
        room = cv2.remap(room, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return room if small == size else cv2.resize(room, size, interpolation=cv2.INTER_LINEAR)


def _writer(path: Path, fps: float, size: tuple[int, int]):
    codec = CODECS.get(path.suffix.lower())
    if codec is None:
        raise ValueError(f"{path.name}: videos are written as {', '.join(CODECS)}")
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*codec), fps, size)
    if not writer.isOpened():
        raise RuntimeError(f"{path}: OpenCV cannot write {codec} video")
    return writer


def render_rig_videos(folder: str | Path, sim, suffix: str = ".mp4", seed: int = 0,
                      progress: Callable[[int, int], None] | None = None) -> dict[str, Path]:
    """Render every camera's video of ``sim`` (a :class:`mvm.sim.rig_scene.RigSimulation`) into
    ``folder/<camera><suffix>`` (``.mp4``, or ``.mkv`` / ``.avi`` lossless) at its frame rate.
    Returns ``{camera: path}``. ``progress(done, total)`` after each frame."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cams, calibration = sim.calibration.cameras, sim.calibration
    rng = np.random.default_rng(seed)
    low, high = MUTED
    textures = [(low + noise_texture(rng, 512).astype(float) * (high - low) / 255).astype(np.uint8)
                for _ in range(6)]
    people = sim.poses3d.shape[1]
    shirts, trousers = rng.uniform(low, high, (people, 3)), rng.uniform(low, 0.5 * (low + high), (people, 3))
    markers = marker_colours(people)
    first = sim.offsets.min()
    total, done, paths = len(cams) * sim.frames, 0, {}
    for v, name in enumerate(cams.names):
        size = (int(cams.size[v, 0]), int(cams.size[v, 1]))
        K, distortion = cams.K[v], calibration.distortions[v]
        room = _room(K, cams.R[v], cams.centers[v], distortion, size, textures)
        path = folder / f"{name}{suffix}"
        writer = _writer(path, sim.frame_rate, size)
        try:
            for f in range(sim.frames):
                X = np.nan_to_num(sim.poses3d[f + sim.offsets[v] - first])                # (G, 17, 3)
                cam = X @ cams.R[v].T + cams.t[v]
                depth = cam[..., 2]
                uv = cam[..., :2] / np.maximum(depth[..., None], 1e-6) * K[[0, 1], [0, 1]] + K[:2, 2]
                uv = distort(uv, K, distortion) if np.any(distortion) else uv
                image = draw_figures(room.copy(), uv, depth, shirts, trousers, float(K[0, 0]), markers=markers)
                writer.write(image)
                done += 1
                if progress:
                    progress(done, total)
        finally:
            writer.release()
        paths[name] = path
    return paths
