"""Calibration boards (no I/O): a checkerboard or a ChArUco board, its corners on the board and
their detection in an image with OpenCV.

A checkerboard is named by its *inner corners* (``cols x rows``, OpenCV's ``patternSize``,
Pose2Sim's ``corners_nb``) and is found by ``cv2.findChessboardCorners`` and refined by
``cv2.cornerSubPix`` (as Pose2Sim and anipose do); its corners are
ordered consistently between views only when one count is even and the other odd (otherwise the
board looks the same turned by 180°). A ChArUco board is named by its *squares* (``cols x
rows``, as OpenCV's ``CharucoBoard`` and anipose) and is found by ``cv2.aruco.CharucoDetector``;
each corner has its id, so a partial view is usable.

Corners on the board (``object_points``): ``x`` along a row of corners, ``y`` across the rows,
``z = 0`` on its face, in metres.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

#: Fewest corners of a usable view (a ChArUco board may be seen in part).
MIN_CORNERS = 6
#: Most inner corners (checkerboard) or squares (ChArUco) along a side of a board: printed
#: calibration boards hold a few dozen; a larger count is a typing error, refused before the scan.
MAX_BOARD_SIDE = 100
#: Checkerboards are found in frames reduced to at most this width (an integer factor), then
#: their corners refined in the full frame: 4K frames cost what HD ones do. [px]
DETECTION_WIDTH = 1280
#: Largest half-side of the window a checkerboard corner is refined in (smaller where the squares
#: are: 0.4 of the shortest side between corners). [px]
SUBPIXEL_HALF_WINDOW = 11
#: Stopping rule of the corners' sub-pixel refinement (iterations, move in pixels).
SUBPIXEL_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
#: The ArUco dictionaries a ChArUco board may use (OpenCV's predefined names).
DICTIONARIES = tuple(sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_") and "ARUCO_MIP" not in n
                            and n != "DICT_ARUCO_ORIGINAL")) + ("DICT_ARUCO_ORIGINAL",)


@dataclass(frozen=True)
class Board:
    """A calibration board.

    Attributes:
        kind: ``"checkerboard"`` or ``"charuco"``.
        cols, rows: inner corners (checkerboard) or squares (ChArUco) along x and y.
        square_m: side of a square. [m]
        marker_m: side of a ChArUco marker. [m]
        dictionary: the ChArUco board's ArUco dictionary (an OpenCV ``DICT_*`` name).
    """

    kind: str
    cols: int
    rows: int
    square_m: float
    marker_m: float | None = None
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self):
        if self.kind not in ("checkerboard", "charuco"):
            raise ValueError(f"board kind: expected checkerboard or charuco, got {self.kind!r}")
        if self.cols < 3 or self.rows < 3:   # OpenCV finds neither board with a count below 3
            raise ValueError(f"board size: at least 3x3, got {self.cols}x{self.rows}")
        if max(self.cols, self.rows) > MAX_BOARD_SIDE:
            raise ValueError(f"board size: at most {MAX_BOARD_SIDE} along a side, got {self.cols}x{self.rows}")
        if not self.square_m > 0:
            raise ValueError(f"square size: expected > 0 m, got {self.square_m}")
        if self.kind == "charuco":
            if self.marker_m is None or not 0 < self.marker_m < self.square_m:
                raise ValueError(f"marker size: expected between 0 and the square size ({self.square_m} m), "
                                 f"got {self.marker_m}")
            if self.dictionary not in DICTIONARIES:
                raise ValueError(f"dictionary: expected an OpenCV name such as DICT_4X4_50, got {self.dictionary!r}")
            size = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)).bytesList.shape[0]
            if size < self.cols * self.rows // 2:
                raise ValueError(f"dictionary: {self.dictionary} holds {size} markers, a board of {self.cols}x"
                                 f"{self.rows} squares needs {self.cols * self.rows // 2}")

    def describe(self) -> str:
        if self.kind == "checkerboard":
            return f"checkerboard of {self.cols}x{self.rows} inner corners, {self.square_m * 1000:g} mm squares"
        return (f"ChArUco board of {self.cols}x{self.rows} squares ({self.square_m * 1000:g} mm, markers "
                f"{self.marker_m * 1000:g} mm, {self.dictionary})")

    @property
    def symmetric(self) -> bool:
        """A checkerboard that looks the same turned by 180° (both corner counts even, or both odd)."""
        return self.kind == "checkerboard" and self.cols % 2 == self.rows % 2

    @cached_property
    def _charuco(self):
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_m, self.marker_m, dictionary)

    @cached_property
    def object_points(self) -> np.ndarray:
        """``(C, 3)`` every corner on the board (metres, ``z = 0``), indexed by corner id."""
        if self.kind == "charuco":
            return np.asarray(self._charuco.getChessboardCorners(), dtype=float).reshape(-1, 3)
        r, c = np.mgrid[:self.rows, :self.cols]
        return np.column_stack([c.ravel(), r.ravel(), np.zeros(r.size)]) * self.square_m

    def texture(self, pixels_per_square: int) -> tuple[np.ndarray, np.ndarray]:
        """The board to print or render, one square of white margin around it: ``(H, W)`` uint8
        and ``A: (3, 3)``, the homography from the board's plane (metres, :attr:`object_points`)
        to its pixels."""
        s = pixels_per_square
        if self.kind == "charuco":
            board = self._charuco.generateImage((self.cols * s, self.rows * s), marginSize=0)
            first = 0.0                                   # the squares' corner is the board's origin
        else:                                             # the top-left square black: the detector's first
            squares = np.add.outer(np.arange(self.rows + 1), np.arange(self.cols + 1)) % 2 == 1   # corner
            board = np.where(np.kron(squares, np.ones((s, s))), 255, 0).astype(np.uint8)
            first = 1.0                                   # the first inner corner is the origin
        image = cv2.copyMakeBorder(board, s, s, s, s, cv2.BORDER_CONSTANT, value=255)
        k = s / self.square_m
        A = np.array([[k, 0, (1 + first) * s - 0.5], [0, k, (1 + first) * s - 0.5], [0, 0, 1]])
        return image, A

    def detector(self):
        """A callable ``gray image (H, W) uint8 -> (ids (n,), pixels (n, 2)) | None``."""
        if self.kind == "charuco":
            found = cv2.aruco.CharucoDetector(self._charuco)

            def detect(gray):
                corners, ids, _, _ = found.detectBoard(gray)
                if ids is None or len(ids) < MIN_CORNERS:
                    return None
                return ids.reshape(-1).astype(int), corners.reshape(-1, 2).astype(float)
            return detect
        size = (self.cols, self.rows)
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK

        def detect(gray):
            shrink = max(1, int(np.ceil(gray.shape[1] / DETECTION_WIDTH)))
            small = gray if shrink == 1 else cv2.resize(gray, (gray.shape[1] // shrink, gray.shape[0] // shrink),
                                                        interpolation=cv2.INTER_AREA)
            ok, corners = cv2.findChessboardCorners(small, size, flags=flags)
            if not ok:
                return None
            corners = ((corners + 0.5) * shrink - 0.5).astype(np.float32)          # pixel centres, full size
            grid = corners.reshape(self.rows, self.cols, 2)
            side = min(np.linalg.norm(np.diff(grid, axis=0), axis=-1).min(),
                       np.linalg.norm(np.diff(grid, axis=1), axis=-1).min())
            half = int(np.clip(round(0.4 * side), 2, SUBPIXEL_HALF_WINDOW))
            corners = cv2.cornerSubPix(gray, corners, (half, half), (-1, -1), SUBPIXEL_CRITERIA)
            return np.arange(self.cols * self.rows), corners.reshape(-1, 2).astype(float)
        return detect


def parse_board_size(text: str) -> tuple[int, int]:
    """``"7x6"`` -> ``(7, 6)``; ValueError otherwise."""
    parts = text.lower().replace("×", "x").split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise ValueError(f"expected COLSxROWS such as 7x6, got {text!r}")
    return int(parts[0]), int(parts[1])


def view_features(pixels: np.ndarray, size: tuple[float, float]) -> np.ndarray:
    """What makes views of a board different for calibrating a lens: ``(6,)`` the centre of the
    corners (over the image size), their spread (over the image diagonal) and their elongation
    and its direction (the second moments: ``(l1 - l2) / (l1 + l2)`` times ``cos 2θ, sin 2θ``),
    and the board's apparent shear. ``pixels: (n, 2)``."""
    w, h = float(size[0]), float(size[1])
    centre = pixels.mean(0)
    d = pixels - centre
    cov = d.T @ d / len(d)
    l1, l2 = np.linalg.eigvalsh(cov)[::-1]
    angle = np.arctan2(2 * cov[0, 1], cov[0, 0] - cov[1, 1])
    elong = (l1 - l2) / max(l1 + l2, 1e-9)
    spread = np.sqrt(l1 + l2) / np.hypot(w, h)
    third = np.cbrt(np.mean(d[:, 0] * d[:, 1] * (d[:, 0] + d[:, 1]))) / max(np.sqrt(l1 + l2), 1e-9)
    return np.array([centre[0] / w, centre[1] / h, 4 * spread, elong * np.cos(angle), elong * np.sin(angle), third])


def spread_views(features: np.ndarray, count: int) -> np.ndarray:
    """Indices of ``count`` views of ``features: (F, D)`` far apart from each other (greedy
    farthest-point sampling from the view nearest the mean), in increasing order."""
    F = len(features)
    if F <= count:
        return np.arange(F)
    chosen = [int(np.argmin(np.linalg.norm(features - features.mean(0), axis=1)))]
    distance = np.linalg.norm(features - features[chosen[0]], axis=1)
    for _ in range(count - 1):
        k = int(np.argmax(distance))
        chosen.append(k)
        distance = np.minimum(distance, np.linalg.norm(features - features[k], axis=1))
    return np.sort(np.array(chosen))
