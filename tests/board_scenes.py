"""Rendered calibration videos with known cameras: a board (checkerboard or ChArUco) moved in
front of a rig whose intrinsics, lenses and poses the tests choose, drawn by warping the board's
image through each camera (homography of its plane, then the lens) and written with
``cv2.VideoWriter``."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from mvm.rig.boards import Board

SIZE = (640, 480)
#: The boards the tests and the board benchmark film: 7x6 inner corners of 70 mm; 6x5 squares
#: of 100 mm with 75 mm markers.
CHECKERBOARD = Board("checkerboard", 7, 6, 0.07)
CHARUCO = Board("charuco", 6, 5, 0.1, 0.075)
#: Supersampling of the rendering (drawn this many times larger, then reduced).
SUPERSAMPLE = 1


@dataclass
class TrueCamera:
    K: np.ndarray
    distortion: np.ndarray
    R: np.ndarray          # world -> camera
    t: np.ndarray
    fisheye: bool = False

    @property
    def centre(self) -> np.ndarray:
        return -self.R.T @ self.t


def look_at(centre, target, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """World -> camera ``R, t`` of a camera at ``centre`` looking at ``target`` (image y down)."""
    centre, target = np.asarray(centre, float), np.asarray(target, float)
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ centre


def ring_cameras(n: int, seed: int = 0, radius: float = 2.2, height: float = 1.8,
                 fisheye: bool = False) -> list[TrueCamera]:
    """``n`` cameras on a ring around the origin, looking down at it, each its own focal length,
    principal point and lens (``fisheye``: OpenCV's fisheye lens, wider, and closer)."""
    rng = np.random.default_rng(seed)
    if fisheye:
        radius, height = 0.6 * radius, 0.6 * height
    cams = []
    for v in range(n):
        a = 2 * np.pi * v / n + 0.3
        R, t = look_at([radius * np.cos(a), radius * np.sin(a), height], [0.05 * v, -0.03 * v, 0.0])
        f = 620 + 40 * v
        K = np.array([[f, 0, 320 + rng.uniform(-12, 12)], [0, f * (1 + rng.uniform(-0.01, 0.01)),
                                                           240 + rng.uniform(-10, 10)], [0, 0, 1]])
        distortion = np.array([-0.12 + 0.03 * v, 0.04, rng.uniform(-1e-3, 1e-3), rng.uniform(-1e-3, 1e-3)])
        if fisheye:
            K[:2, :2] *= 0.6
            distortion = np.array([0.05 - 0.02 * v, -0.02, 0.01, -0.005])
        cams.append(TrueCamera(K, distortion, R, t, fisheye))
    return cams


def _rotation(axis, angle) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(axis, float) * angle)[0]


#: The board lying on the floor, its face up: board x along world x, board y along world -y.
FLOOR = np.diag([1.0, -1.0, -1.0])


def floor_board_poses(n: int, board: Board, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` poses (board -> world ``R (n, 3, 3)``, ``t (n, 3)``) of a board moved and tilted
    about on the floor near the origin; the first lies flat, its first corner at ``FIRST_CORNER``."""
    rng = np.random.default_rng(seed)
    middle = board.object_points.max(0) / 2
    R, t = [FLOOR], [FIRST_CORNER]
    for k in range(1, n):
        tilt = _rotation(rng.normal(size=3) * [1, 1, 0] / 1.0, np.radians(rng.uniform(5, 28)))
        spin = _rotation([0, 0, 1], rng.uniform(-0.6, 0.6))
        Rk = tilt @ spin @ FLOOR
        centre = np.array([0.25 * np.cos(k), 0.25 * np.sin(1.3 * k), 0.3 + 0.15 * np.sin(0.7 * k)])
        R.append(Rk)
        t.append(centre - Rk @ middle)
    return np.array(R), np.array(t)


FIRST_CORNER = np.array([-0.3, 0.25, 0.0])


def frontal_board_poses(n: int, board: Board, camera: TrueCamera, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` poses of a board held in front of ``camera`` (board -> world) at 0.8 to 1.5 m,
    over the image and tilted up to 40°, for its intrinsics."""
    rng = np.random.default_rng(seed)
    middle = board.object_points.max(0) / 2
    R, t = [], []
    for _ in range(n):
        depth = rng.uniform(0.8, 1.5)
        u = np.array([rng.uniform(0.3, 0.7) * SIZE[0], rng.uniform(0.3, 0.7) * SIZE[1], 1.0])
        target_cam = depth * np.linalg.inv(camera.K) @ u
        tilt = _rotation(rng.normal(size=3) * [1, 1, 0.3], np.radians(rng.uniform(0, 40)))
        R_cam = tilt                                                          # board -> camera, facing it
        t_cam = target_cam - R_cam @ middle
        R.append(camera.R.T @ R_cam)
        t.append(camera.R.T @ (t_cam - camera.t))
    return np.array(R), np.array(t)


def lens_grid(camera: TrueCamera) -> np.ndarray:
    """The pinhole pixel of every (supersampled) pixel of the distorted image: ``(h, w, 2)``."""
    s = SUPERSAMPLE
    w, h = SIZE[0] * s, SIZE[1] * s
    jj, ii = np.meshgrid(np.arange(w), np.arange(h))
    pixels = np.stack([(jj + 0.5) / s - 0.5, (ii + 0.5) / s - 0.5], -1).reshape(-1, 1, 2).astype(np.float64)
    if camera.fisheye:
        pinhole = cv2.fisheye.undistortPoints(pixels, camera.K, camera.distortion, P=camera.K)
    else:
        pinhole = cv2.undistortPoints(pixels, camera.K, camera.distortion, P=camera.K)
    return pinhole.reshape(h, w, 2).astype(np.float32)


def render(board: Board, texture, A, camera: TrueCamera, grid, R_board, t_board, background: int = 110) -> np.ndarray:
    """The board at pose ``R_board, t_board`` (board -> world) seen by ``camera``: ``(H, W, 3)`` BGR."""
    R_bc = camera.R @ R_board
    t_bc = camera.R @ t_board + camera.t
    H = camera.K @ np.column_stack([R_bc[:, 0], R_bc[:, 1], t_bc])                 # board plane -> pinhole
    M = (A @ np.linalg.inv(H)).astype(np.float32)
    u = grid @ M[:, :2].T + M[:, 2]                                               # (h, w, 3)
    w = u[..., 2]
    w = np.where(w > 1e-6, w, np.nan)                                             # behind the board's plane
    mapped = np.nan_to_num(u[..., :2] / w[..., None], nan=-1e4)
    big = cv2.remap(texture, np.ascontiguousarray(mapped[..., 0]), np.ascontiguousarray(mapped[..., 1]),
                    cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=background)
    image = cv2.resize(big, SIZE, interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)


def write_board_video(path: Path, board: Board, camera: TrueCamera, R_board: np.ndarray, t_board: np.ndarray,
                      fps: float = 10.0, blank: tuple[int, ...] = ()) -> None:
    """A video of the board at each pose (``blank``: frames drawn without the board)."""
    texture, A = board.texture(24 * SUPERSAMPLE)
    grid = lens_grid(camera)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, SIZE)
    for k, (R, t) in enumerate(zip(R_board, t_board)):
        frame = render(board, texture, A, camera, grid, R, t)
        if k in blank:
            frame[:] = 110
        writer.write(frame)
    writer.release()


def seen_corners(board: Board, camera: TrueCamera, R_board, t_board) -> np.ndarray:
    """``(n, C, 2)`` the true (distorted) pixels of the board's corners at each pose."""
    X = np.einsum("nij,cj->nci", R_board, board.object_points) + t_board[:, None]
    rvec = cv2.Rodrigues(camera.R)[0]
    if camera.fisheye:
        px, _ = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), rvec, camera.t, camera.K, camera.distortion)
    else:
        px, _ = cv2.projectPoints(X.reshape(-1, 3), rvec, camera.t, camera.K, camera.distortion)
    return px.reshape(len(R_board), -1, 2)


@dataclass
class BoardRig:
    """A rendered calibration: the true ``cameras`` and the world's offset (the board of frame 0
    has its first corner at ``FIRST_CORNER``, its face up)."""

    cameras: list
    names: list


def write_board_rig(root: Path, board: Board, n_cameras: int = 3, intrinsic_frames: int = 20,
                    extrinsic_frames: int = 24, layout: str = "split", blank: dict | None = None,
                    seed: int = 0, fisheye: bool = False) -> BoardRig:
    """Calibration videos of ``n_cameras`` ring cameras in ``root/calibration``: ``layout``
    "split" (``intrinsics/`` and ``extrinsics/``) or "flat" (the extrinsics videos right in
    ``calibration/``, no intrinsics videos). ``blank``: ``{camera: frames}`` of the extrinsics
    videos drawn without the board."""
    cams = ring_cameras(n_cameras, seed, fisheye=fisheye)
    names = [f"cam_{v + 1:02d}" for v in range(n_cameras)]
    R_floor, t_floor = floor_board_poses(extrinsic_frames, board, seed)
    folder = root / "calibration"
    for v, (cam, name) in enumerate(zip(cams, names)):
        if layout == "split":
            R, t = frontal_board_poses(intrinsic_frames, board, cam, seed=seed + v)
            write_board_video(folder / "intrinsics" / f"{name}.mp4", board, cam, R, t)
        where = folder / "extrinsics" if layout == "split" else folder
        write_board_video(where / f"{name}.mp4", board, cam, R_floor, t_floor, blank=(blank or {}).get(v, ()))
    return BoardRig(cams, names)


def true_cameras(cameras: list, names: list | None = None):
    """The :class:`TrueCamera` list as :class:`~mvm.core.scene.Cameras` (``SIZE`` images; names
    ``cam1 ..`` unless given)."""
    from mvm.core.scene import Cameras

    names = names or [f"cam{v + 1}" for v in range(len(cameras))]
    return Cameras(np.array([c.K for c in cameras]), np.array([c.R for c in cameras]), np.array([c.t for c in cameras]),
                   np.array([SIZE] * len(cameras), float), tuple(names), tuple(c.distortion for c in cameras),
                   np.array([c.fisheye for c in cameras]))


def write_true_calibration(path: Path, cameras: list, names: list) -> Path:
    """The true cameras as a Calib.toml (for ``--intrinsics``)."""
    from mvm.io.calib_toml import RigCalibration, write_calib_toml

    write_calib_toml(path, RigCalibration(true_cameras(cameras, names)))
    return path


def write_still_board(paths: list, board: Board, cameras: list) -> None:
    """One image per camera of the board lying on the floor (the first pose of
    :func:`floor_board_poses`), at ``paths``."""
    R, t = floor_board_poses(1, board)
    texture, A = board.texture(24)
    for cam, path in zip(cameras, paths):
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(path), render(board, texture, A, cam, lens_grid(cam), R[0], t[0]))
