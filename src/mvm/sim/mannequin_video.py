"""A synthetic mannequin video with ground truth: a textured room, coloured people-like
figures and a hand-held camera touring them.

World frame: metres, z up, floor at z = 0. The room is a box whose walls, floor and ceiling
carry multi-scale noise textures (so that SIFT finds features); people are capsules (limbs,
torso) and a disc (head), drawn far to near with OpenCV.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from mvm.core.config import check_settings, setting
from mvm.core.keypoints import NUM_JOINTS
from mvm.core.scene import Cameras
from mvm.sim.people import STANDING
from mvm.sim.tours import cameras_looking_at

#: Body parts drawn as capsules: (joint a, joint b, radius in metres, clothing part).
#: Parts: 0 shirt (torso and upper arms), 1 trousers (legs), 2 skin (forearms).
_PARTS = (
    (5, 11, 0.11, 0), (6, 12, 0.11, 0), (5, 12, 0.11, 0), (6, 11, 0.11, 0),
    (5, 7, 0.05, 0), (6, 8, 0.05, 0), (7, 9, 0.04, 2), (8, 10, 0.04, 2),
    (11, 13, 0.07, 1), (12, 14, 0.07, 1), (13, 15, 0.055, 1), (14, 16, 0.055, 1),
)
_SKIN = np.array([150, 180, 220], dtype=float)  # BGR
_HEAD_RADIUS = 0.11


@dataclass(frozen=True)
class RenderConfig:
    """A rendered tour. Lengths in metres, angles in degrees, sizes in pixels."""

    #: Frames of the tour. [frames]
    frames: int = setting(48, ge=2, le=100_000)
    #: Width of the frames. [px]
    width: int = setting(480, ge=16, le=16384)
    #: Height of the frames. [px]
    height: int = setting(270, ge=16, le=16384)
    #: Focal length; lower widens the field of view. [px]
    focal_px: float = setting(400.0, gt=0)
    #: Frame rate of the video. [Hz]
    fps: float = setting(24.0, gt=0, le=1000)
    #: Total angle of the camera's arc around the crowd; wider gives more parallax. [deg]
    arc_deg: float = setting(60.0, gt=0, le=360)
    #: Radius of the camera's arc. [m]
    radius: float = setting(4.0, gt=0)
    #: Height of the camera above the floor. [m]
    camera_height: float = setting(1.6, ge=0)
    #: Hand-held shake of the camera centre (standard deviation). [m]
    shake_m: float = setting(0.01, ge=0)
    #: Half-size of the room's floor (a square). [m]
    room_half: float = setting(7.0, gt=0)
    #: Height of the room. [m]
    room_height: float = setting(3.5, gt=0)
    #: Seed of the camera's shake and the room's textures. [1]
    seed: int = setting(0, ge=0, le=2**63 - 1)

    def __post_init__(self):
        check_settings(self)


@dataclass
class RenderedScene:
    """The truth of a rendered video: ``cameras`` (V views), ``poses3d: (G, 17, 3)``,
    ``shirts: (G, 3)`` and ``trousers: (G, 3)`` BGR colours."""

    cameras: Cameras
    poses3d: np.ndarray
    shirts: np.ndarray
    trousers: np.ndarray


def noise_texture(rng: np.random.Generator, size: int = 1024, octaves: int = 7) -> np.ndarray:
    """A coloured multi-scale noise texture: ``(size, size, 3)`` uint8."""
    texture = np.zeros((size, size, 3), dtype=np.float32)
    for o in range(octaves):
        cells = 4 * 2**o
        small = rng.uniform(-1, 1, (cells, cells, 3)).astype(np.float32)
        texture += cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC) / (1.15**o)
    texture -= texture.min()
    texture *= 230.0 / texture.max()
    return np.clip(texture + 10, 0, 255).astype(np.uint8)


def _room_planes(config: RenderConfig):
    """The 6 planes of the room: (axis, offset, in-plane axes (2,)) each."""
    h, H = config.room_half, config.room_height
    return [(0, -h, (1, 2)), (0, h, (1, 2)), (1, -h, (0, 2)), (1, h, (0, 2)), (2, 0.0, (0, 1)), (2, H, (0, 1))]


def render_room(K: np.ndarray, R: np.ndarray, center: np.ndarray, size: tuple[int, int],
                textures: list[np.ndarray], config: RenderConfig) -> np.ndarray:
    """Ray-cast the textured room for one camera: ``(H, W, 3)`` uint8 BGR.

    ``K: (3, 3)``, ``R: (3, 3)`` world -> camera, ``center: (3,)``.
    """
    W, H = size
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rays = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(K).T @ R     # (H, W, 3) world
    image = np.zeros((H, W, 3), dtype=np.uint8)
    best = np.full((H, W), np.inf)
    metres_per_texel = 2 * config.room_half / textures[0].shape[0]
    for (axis, offset, (a, b)), texture in zip(_room_planes(config), textures):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (offset - center[axis]) / rays[..., axis]
        hit = np.isfinite(t) & (t > 0) & (t < best)
        if not hit.any():
            continue
        point = center + np.where(hit, t, 0)[..., None] * rays
        map_x = ((point[..., a] + config.room_half) / metres_per_texel).astype(np.float32)
        map_y = ((point[..., b] + config.room_half) / metres_per_texel).astype(np.float32)
        sampled = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        image[hit] = sampled[hit]
        best = np.where(hit, t, best)
    return image


def draw_people(image: np.ndarray, P: np.ndarray, poses3d: np.ndarray, shirts: np.ndarray,
                trousers: np.ndarray, focal: float, brightness: float = 1.0) -> np.ndarray:
    """Draw people as capsules, far to near, on ``image: (H, W, 3)`` (in place).

    ``P: (3, 4)``, ``poses3d: (G, 17, 3)``, ``shirts, trousers: (G, 3)`` BGR.
    """
    G = len(poses3d)
    x = np.concatenate([poses3d, np.ones((G, NUM_JOINTS, 1))], axis=2) @ P.T
    depth = x[..., 2]
    uv = x[..., :2] / np.maximum(depth[..., None], 1e-6)
    return draw_figures(image, uv, depth, shirts, trousers, focal, brightness)


#: The radius of a joint's marker (:func:`draw_figures`). [m]
MARKER_RADIUS = 0.03


def draw_figures(image: np.ndarray, uv: np.ndarray, depth: np.ndarray, shirts: np.ndarray, trousers: np.ndarray,
                 focal: float, brightness: float = 1.0, markers: np.ndarray | None = None) -> np.ndarray:
    """Draw projected people as capsules, far to near, on ``image: (H, W, 3)`` (in place).

    ``uv: (G, 17, 2)`` pixels, ``depth: (G, 17)`` metres along the optical axis, ``shirts,
    trousers: (G, 3)`` BGR. ``markers: (G, 17, 3)`` BGR: a disc of :data:`MARKER_RADIUS` on each
    joint in exactly that colour (no anti-aliasing), drawn over its own person's body and hidden
    by other people nearer; the nose's and the eyes' markers are not drawn when they are behind
    the head's centre (the person faces away).
    """
    G = len(uv)
    items = []  # (depth, kind, person, part index)
    for g in range(G):
        parts = [0.5 * (depth[g, a] + depth[g, b]) for a, b, _, _ in _PARTS]
        items += [(d, 0, g, k) for k, d in enumerate(parts)]
        items.append((depth[g, 0], 1, g, -1))
        if markers is not None:
            items += _marker_items(depth[g], parts, g)
    items.sort(key=lambda item: -item[0])
    for d, kind, g, k in items:
        if d <= 0.1:
            continue
        if kind == 2:
            radius = max(int(round(focal * MARKER_RADIUS / depth[g, k])), 2)
            centre = tuple(int(round(c)) for c in uv[g, k])
            cv2.circle(image, centre, radius, [int(c) for c in markers[g, k]], -1, cv2.LINE_8)
            continue
        if kind == 1:
            head = 0.5 * (uv[g, 3] + uv[g, 4])
            radius = max(int(round(focal * _HEAD_RADIUS / d)), 1)
            colour = _SKIN * brightness
            cv2.circle(image, tuple(int(round(c)) for c in head), radius, colour.tolist(), -1, cv2.LINE_AA)
            continue
        a, b, r, part = _PARTS[k]
        colour = (shirts[g], trousers[g], _SKIN)[part] * brightness
        thickness = max(int(round(2 * focal * r / d)), 1)
        pa = tuple(int(round(c)) for c in uv[g, a])
        pb = tuple(int(round(c)) for c in uv[g, b])
        cv2.line(image, pa, pb, np.clip(colour, 0, 255).tolist(), thickness, cv2.LINE_AA)
    return image


def _marker_items(depth: np.ndarray, parts: list[float], g: int) -> list[tuple]:
    """The marker items of person ``g`` (``depth: (17,)``, ``parts``: the sort depth of each of
    its capsules): sorted just in front of the person's nearest part, so that a marker shows
    through its own body (a detector infers the joints a body hides of itself) and is hidden by
    other people nearer; the nose's and the eyes' markers are left out when they are behind the
    head's centre (the person faces away)."""
    behind_head = 0.5 * (depth[3] + depth[4])
    front = min(min(parts), depth[0]) - 1e-6
    return [(front, 2, g, j) for j in range(NUM_JOINTS) if not (j < 3 and depth[j] > behind_head)]


def tour_cameras(config: RenderConfig, rng: np.random.Generator) -> Cameras:
    """``config.frames`` cameras on an arc around the origin, looking at (0, 0, 1)."""
    V = config.frames
    angles = np.radians(-90 + config.arc_deg * np.linspace(-0.5, 0.5, V))
    centers = np.stack([config.radius * np.cos(angles), config.radius * np.sin(angles),
                        np.full(V, config.camera_height)], axis=1)
    centers += rng.normal(0, config.shake_m, (V, 3))
    return cameras_looking_at(centers, [0.0, 0.0, 1.0], (config.focal_px, config.focal_px),
                              (config.width, config.height))


def default_people(rng: np.random.Generator, count: int = 3, spacing: float = 0.9) -> np.ndarray:
    """``count`` standing people in a row along x, facing -y (towards the tour): ``(G, 17, 3)``."""
    poses = []
    for g in range(count):
        pose = STANDING * rng.uniform(0.9, 1.08) + rng.normal(0, 0.015, STANDING.shape)
        pose[:, :2] *= -1  # a half turn about z: face -y
        pose += [(g - (count - 1) / 2) * spacing, rng.uniform(-0.3, 0.3), 0.0]
        poses.append(pose)
    return np.array(poses)


def render_video(path: str | Path, config: RenderConfig = RenderConfig(),
                 poses3d: np.ndarray | None = None, shirts: np.ndarray | None = None,
                 trousers: np.ndarray | None = None) -> RenderedScene:
    """Render the tour and write it as an mp4 (``mp4v``) video at ``path``; return the truth."""
    rng = np.random.default_rng(config.seed)
    textures = [noise_texture(rng) for _ in range(6)]
    cameras = tour_cameras(config, rng)
    poses3d = default_people(rng) if poses3d is None else np.asarray(poses3d, dtype=float)
    G = len(poses3d)
    shirts = rng.uniform(40, 230, (G, 3)) if shirts is None else np.asarray(shirts, dtype=float)
    trousers = rng.uniform(20, 120, (G, 3)) if trousers is None else np.asarray(trousers, dtype=float)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), config.fps,
                             (config.width, config.height))
    if not writer.isOpened():
        raise RuntimeError(f"{path}: OpenCV cannot write mp4v video")
    try:
        for v in range(len(cameras)):
            image = render_room(cameras.K[v], cameras.R[v], cameras.centers[v],
                                (config.width, config.height), textures, config)
            draw_people(image, cameras.P[v], poses3d, shirts, trousers, config.focal_px)
            writer.write(image)
    finally:
        writer.release()
    return RenderedScene(cameras, poses3d, shirts, trousers)


def render_frames(out_dir: str | Path, cameras: Cameras, poses3d: np.ndarray, seed: int = 0,
                  config: RenderConfig = RenderConfig(),
                  progress: Callable[[int, int], None] | None = None) -> list[Path]:
    """Render the frame of every camera of a scene into ``out_dir`` under its camera name.

    ``poses3d: (G, 17, 3)`` in the cameras' world (metres, z up); the room of ``config``
    surrounds them. Frames are written atomically; returns their paths. ``progress(done,
    total)`` before the first frame and after each.
    """
    from mvm.io.files import atomic_write_bytes

    rng = np.random.default_rng(seed)
    textures = [noise_texture(rng) for _ in range(6)]
    poses3d = np.asarray(poses3d, dtype=float)
    shirts, trousers = rng.uniform(40, 230, (len(poses3d), 3)), rng.uniform(20, 120, (len(poses3d), 3))
    out_dir = Path(out_dir)
    paths = []
    if progress:
        progress(0, len(cameras))
    for v in range(len(cameras)):
        size = (int(cameras.size[v, 0]), int(cameras.size[v, 1]))
        image = render_room(cameras.K[v], cameras.R[v], cameras.centers[v], size, textures, config)
        draw_people(image, cameras.P[v], np.nan_to_num(poses3d), shirts, trousers, float(cameras.K[v, 0, 0]))
        ok, data = cv2.imencode(Path(cameras.names[v]).suffix or ".jpg", image)
        if not ok:
            raise ValueError(f"{cameras.names[v]}: OpenCV cannot encode this image type")
        path = out_dir / cameras.names[v]
        atomic_write_bytes(path, data.tobytes())
        paths.append(path)
        if progress:
            progress(v + 1, len(cameras))
    return paths
