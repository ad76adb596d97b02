"""Calibrating a rig from videos or photos of a board (:mod:`mvm.rig.board_calibration`): find
the sources, stream their frames and find the board in them, calibrate, write a Calib.toml.
Every problem is one :class:`~mvm.errors.InputError` naming the camera or the file, and nothing
is written then.

::

    RIG_DIR/calibration/
      intrinsics/<camera>.<ext>   optional: the board moved in front of each camera alone
      extrinsics/<camera>.<ext>   the board seen by several cameras at once (videos recorded
                                  together: frame n of each is the same instant)
      <camera>.<ext>              or the videos right in calibration/ (anipose): both from them

A camera without an intrinsics video is calibrated on its extrinsics video. A camera's video
may also be a folder of images (``<camera>/`` holding ``*.png``, ``*.jpg``, ... in name order,
as Pose2Sim's ``int_<camera>_img/``), a folder holding one video (Pose2Sim's
``int_<camera>_vid/``) or, for the extrinsics of a board lying still, one image. The cameras are
named after the files and folders, less the words all of them share
(:func:`~mvm.core.names.without_shared_words`: ``int_cam01_img`` is ``cam01``), and ordered by
name (the first is the reference), or as in ``--intrinsics FILE``.
:func:`calibrate_intrinsics_from_board` calibrates the intrinsics alone, each camera on its own,
from ``intrinsics/`` (else the sources right in ``calibration/``).
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from mvm.core.names import natural_key, without_shared_words
from mvm.core.scene import Cameras
from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration, write_calib_toml
from mvm.io.images import frame_count_bound, read_image, step_frames
from mvm.io.layout import CALIBRATION_DIR, EXTRINSICS_DIR, INTRINSICS_DIR
from mvm.io.outputs import check_output_location
from mvm.io.paths import VIDEO_SUFFIXES
from mvm.parallel import available_workers
from mvm.rig.board_calibration import (
    BoardRig,
    Intrinsics,
    calibrate_extrinsics,
    calibrate_intrinsics,
)
from mvm.rig.boards import MIN_CORNERS, Board
from mvm.rig.calibrate import CalibrationError
from mvm.rig.rigdir import match_cameras, read_calibration

IMAGE_EXTENSIONS = frozenset((".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff"))
#: Frames of a video searched for the board, at most (evenly spaced; the same frame numbers in
#: every camera, so that the extrinsics videos' views stay simultaneous). [frames]
MAX_SCANNED_FRAMES = 300


def _images(folder: Path) -> list[Path]:
    """The images of ``folder`` in name order; an image name on something that is not a file (a
    FIFO, a folder, a broken link: leaving it out would shift the frame numbers after it) raises
    :class:`InputError`."""
    images = [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS]
    for p in images:
        if not p.is_file():
            raise InputError(p, None, "named like an image but not a file (a FIFO, a folder or a broken link)")
    return sorted(images, key=lambda p: natural_key(p.name))


def _folder_source(folder: Path) -> Path | None:
    """What a camera's folder holds: its images (the folder itself), its one video (returned), or
    nothing (None). Images beside a video, or several videos, raise :class:`InputError`."""
    images = _images(folder)
    videos = sorted((p for p in folder.iterdir() if p.suffix.lower() in VIDEO_SUFFIXES and not p.name.startswith(".")),
                    key=lambda p: natural_key(p.name))
    if videos and images:
        raise InputError(folder, None, f"holds images and a video ({videos[0].name}): keep one or the other")
    if len(videos) > 1:
        raise InputError(folder, None, f"holds {len(videos)} videos ({videos[0].name}, {videos[1].name}): "
                                       "keep one per camera")
    if videos and not videos[0].is_file():
        raise InputError(videos[0], None, "named like a video but not a file (a FIFO, a folder or a broken link)")
    return videos[0] if videos else folder if images else None


#: The folders of ``calibration/`` that hold cameras, not a camera.
LAYOUT_FOLDERS = frozenset(("intrinsics", "extrinsics"))


def calibration_sources(folder: Path) -> dict[str, Path]:
    """``{camera: video, image or image folder}`` of ``folder``, ordered by name, the cameras
    named without the words all the names share (:func:`~mvm.core.names.without_shared_words`).
    A video or image name on something that is neither a file nor a folder (a FIFO, a broken
    link: its camera would be left out unsaid) or a camera's folder with no image or video raises
    :class:`InputError`, as :func:`mvm.io.paths.videos_by_name` does."""
    if not folder.is_dir():
        return {}
    found = {}
    for p in folder.iterdir():
        if p.name.startswith(".") or p.is_dir() and p.name in LAYOUT_FOLDERS:
            continue
        typed = p.suffix.lower() in IMAGE_EXTENSIONS or p.suffix.lower() in VIDEO_SUFFIXES
        if typed and not p.is_file() and not p.is_dir():
            raise InputError(p, None, "named like a video or image but not a file (a FIFO or a broken link)")
        source = _folder_source(p) if p.is_dir() else p if typed else None
        if p.is_dir() and source is None:
            raise InputError(p, None, f"no image ({', '.join(sorted(IMAGE_EXTENSIONS))}) or video in this camera's "
                                      "folder")
        if source is not None:
            name = p.stem if p.is_file() else p.name
            if name in found:
                raise InputError(p, None, f"camera {name}: two calibration sources ({found[name].name} and {p.name})")
            found[name] = source
    names = sorted(found, key=natural_key)
    return dict(zip(without_shared_words(names), (found[n] for n in names)))


def rig_videos(rig_dir: Path) -> tuple[dict[str, Path], dict[str, Path]]:
    """The intrinsics and extrinsics sources of ``rig_dir`` (module docstring)."""
    root = rig_dir / CALIBRATION_DIR
    extrinsics = calibration_sources(root / EXTRINSICS_DIR) or calibration_sources(root)
    if not extrinsics:
        raise InputError(root, None, "no calibration videos: expected calibration/extrinsics/<camera>.<ext> "
                                     "(and optionally calibration/intrinsics/<camera>.<ext>), or "
                                     "calibration/<camera>.<ext>")
    return calibration_sources(root / INTRINSICS_DIR), extrinsics


def frame_count(source: Path) -> int:
    """Frames of a video (its header's count, bounded: :func:`mvm.io.images.frame_count_bound`;
    0 when it does not say) or images of a folder."""
    if source.is_dir():
        return len(_images(source))
    if source.suffix.lower() in IMAGE_EXTENSIONS:
        return 1
    capture = cv2.VideoCapture(str(source))
    try:
        return frame_count_bound(source, capture.get(cv2.CAP_PROP_FRAME_COUNT)) if capture.isOpened() else 0
    finally:
        capture.release()


def gray_frames(source: Path, stride: int):
    """Every ``stride``-th frame of a video or image folder, one at a time: yields ``(number,
    gray (H, W) uint8)``; the frames in between are skipped undecoded. A video that does not open
    or decode, or an image that is not a regular file of bounded size OpenCV decodes
    (:func:`mvm.io.images.read_image`), raises :class:`InputError`."""
    if source.is_dir() or source.suffix.lower() in IMAGE_EXTENSIONS:
        for number, path in enumerate(_images(source) if source.is_dir() else [source]):
            if number % stride == 0:
                yield number, read_image(path, flags=cv2.IMREAD_GRAYSCALE)
        return
    capture = cv2.VideoCapture(str(source))
    try:
        if not capture.isOpened():
            raise InputError(source, None, "OpenCV cannot open this video")
        decoded = False                                      # frame 0, always wanted, decodes
        for number, image in step_frames(capture, lambda n: n % stride == 0, video=source):
            decoded = True
            yield number, cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if not decoded:
            raise InputError(source, None, "OpenCV cannot decode this video")
    finally:
        capture.release()


@dataclass
class BoardScan:
    """The board found in one camera's video: ``frames (F,)`` the frame numbers searched,
    ``corners (F, C, 2)`` (pixels, NaN: not found), ``size`` (width, height)."""

    frames: np.ndarray
    corners: np.ndarray
    size: tuple[int, int]

    @property
    def found(self) -> int:
        """The frames searched in which the board is found."""
        return int(np.isfinite(self.corners).all(-1).any(-1).sum())


def scan(source: Path, board: Board, stride: int, progress=None, count: int | None = None) -> BoardScan:
    """Find ``board`` in every ``stride``-th frame of ``source``; ``progress(done, total)``
    after each (total None where the video's header does not say). ``count``: its
    :func:`frame_count`, when already read."""
    detect = board.detector()
    total = math.ceil((frame_count(source) if count is None else count) / stride) or None
    C = len(board.object_points)
    frames, corners, size = [], [], None
    for number, gray in gray_frames(source, stride):
        if size is None:
            size = (gray.shape[1], gray.shape[0])
        elif (gray.shape[1], gray.shape[0]) != size:
            if _is_photos(source):
                images = _images(source)
                raise InputError(images[number], None, f"{gray.shape[1]}x{gray.shape[0]} pixels, {images[0].name} "
                                                       f"has {size[0]}x{size[1]}: one camera, one image size")
            raise InputError(source, f"frame {number}", f"{gray.shape[1]}x{gray.shape[0]} pixels, the first "
                                                        f"frame has {size[0]}x{size[1]}")
        found = detect(gray)
        view = np.full((C, 2), np.nan)
        if found is not None:
            view[found[0]] = found[1]
        frames.append(number)
        corners.append(view)
        if progress is not None:
            progress(len(frames), max(total or 0, len(frames)) or None)
    return BoardScan(np.array(frames, dtype=int), np.array(corners).reshape(-1, C, 2), size)


def scan_all(jobs: list[tuple[str, Path, int, int]], board: Board, workers: int | None, progress=None
             ) -> list[BoardScan]:
    """:func:`scan` of every ``(label, source, stride, frames)`` in threads (OpenCV's decoding and
    detection release the GIL); ``progress(label, done, total)``."""
    if not jobs:
        return []
    def one(job):
        label, source, stride, frames = job
        return scan(source, board, stride, None if progress is None else lambda d, t: progress(label, d, t), frames)

    with ThreadPoolExecutor(min(len(jobs), available_workers(workers))) as pool:
        futures = [pool.submit(one, job) for job in jobs]
        try:
            return [f.result() for f in futures]
        except BaseException:
            for f in futures:
                f.cancel()
            raise


def scan_stride(counts) -> int:
    """The stride that scans at most ``MAX_SCANNED_FRAMES`` of the longest of videos of ``counts`` frames."""
    return max(1, math.ceil(max(counts) / MAX_SCANNED_FRAMES))


def _is_photos(source: Path) -> bool:
    """A source of images (a folder of them, or one), not a video."""
    return source.is_dir() or source.suffix.lower() in IMAGE_EXTENSIONS


def searched(scan_: BoardScan, source: Path) -> str:
    """What was searched for the board: ``"7 images"``, ``"300 frames"``."""
    n = len(scan_.frames)
    return f"{n} {'image' if _is_photos(source) else 'frame'}{'s' if n != 1 else ''}"


def _check_found(scan_: BoardScan, source: Path, name: str, board: Board, more: str = "") -> None:
    if not scan_.found:
        hint = ("--board-size counts inner corners" if board.kind == "checkerboard" else
                "--board-size counts squares; check --dictionary") + more
        raise InputError(source, None, f"camera {name}: no {board.describe()} found in the "
                                       f"{searched(scan_, source)} searched ({hint})")


def lens_cameras(names: list[str], lenses: list[Intrinsics], scans: list[BoardScan], fisheye: bool) -> Cameras:
    """The ``V`` cameras of ``names`` with the intrinsics and lens of ``lenses`` and the image
    size of ``scans`` (their rotations and translations unknown: NaN)."""
    V = len(names)
    return Cameras(np.array([lens.K for lens in lenses]), np.full((V, 3, 3), np.nan), np.full((V, 3), np.nan),
                   np.array([s.size for s in scans], dtype=float), tuple(names),
                   tuple(lens.distortion for lens in lenses), np.full(V, fisheye))


def camera_lens(scan_: BoardScan, source: Path, name: str, board: Board, fisheye: bool) -> Intrinsics:
    """A camera's :class:`Intrinsics` from its scan (the board found in it)."""
    _check_found(scan_, source, name, board)
    try:
        return calibrate_intrinsics(scan_.corners, board.object_points, scan_.size, fisheye=fisheye)
    except CalibrationError as e:
        raise InputError(source, None, f"camera {name}: {e.problem} ({searched(scan_, source)} searched)") from None


@dataclass
class RigBoardCalibration:
    """A calibration from a board: ``calibration`` (written at ``path``), each camera's
    ``intrinsics`` (:class:`~mvm.rig.board_calibration.Intrinsics`; None: from a file), the
    ``rig`` (:class:`~mvm.rig.board_calibration.BoardRig`) and the extrinsics ``frames`` (the
    common frame numbers; ``rig.world_view`` indexes them)."""

    calibration: RigCalibration
    intrinsics: list
    rig: BoardRig
    frames: np.ndarray
    path: Path


def _given_intrinsics(path: Path, names: list[str]) -> RigCalibration:
    """The intrinsics of ``path`` for the cameras with videos, in that file's order."""
    calibration = read_calibration(path, extrinsics=False)
    file_names = calibration.cameras.names
    matched = match_cameras(file_names, names)
    missing = [n for i, n in enumerate(names) if i not in matched.values()]
    if missing:
        raise InputError(path, None, f"no camera matches the calibration video of {', '.join(missing)}")
    index = np.array(sorted(matched))
    cams = calibration.cameras.subset(index)
    return RigCalibration(replace(cams, names=tuple(names[matched[i]] for i in index)),
                          calibration.metadata)


def intrinsic_videos(names: list[str], sources: dict[str, Path]) -> dict[str, Path]:
    """``{camera: intrinsics video}``, matched to the cameras by name as pose folders are
    (:func:`~mvm.rig.rigdir.match_cameras`: ``int_cam01_img`` goes with ``ext_cam01_img``); a
    video no camera matches raises :class:`InputError`."""
    entries = list(sources)
    matched = match_cameras(names, entries)
    unmatched = sorted(set(range(len(entries))) - set(matched.values()))
    if unmatched:
        source = sources[entries[unmatched[0]]]
        raise InputError(source, None, f"no extrinsics video of the same camera (cameras: {', '.join(names)})")
    return {names[c]: sources[entries[e]] for c, e in matched.items()}


def _calibrate_lenses(names, intrinsic_sources, ext_scans, ext_sources, board, workers, progress, fisheye):
    """Each camera's :class:`Intrinsics`: on its intrinsics video, else on its extrinsics video."""
    videos = intrinsic_videos(names, intrinsic_sources)
    own = [n for n in names if n in videos]
    counts = {n: frame_count(videos[n]) for n in own}
    scans = dict(zip(own, scan_all([(f"{n} intrinsics", videos[n], scan_stride([counts[n]]), counts[n])
                                    for n in own], board, workers, progress)))
    found = []
    for v, name in enumerate(names):
        s, source = (scans[name], videos[name]) if name in scans else (ext_scans[v], ext_sources[name])
        if s.size != ext_scans[v].size:
            raise InputError(source, None, f"camera {name}: {s.size[0]}x{s.size[1]} pixels, its extrinsics video "
                                           f"{ext_scans[v].size[0]}x{ext_scans[v].size[1]}: calibrate at one size")
        found.append(camera_lens(s, source, name, board, fisheye))
    return found


def _corners_by_frame(scans: list[BoardScan]) -> tuple[np.ndarray, np.ndarray]:
    """``(frames (F,), corners (V, F, C, 2))``: the frames any camera searched and each camera's
    board corners in them (NaN: not searched or not found), from the scans of ``V`` cameras."""
    frames = np.unique(np.concatenate([s.frames for s in scans]))
    corners = np.full((len(scans), len(frames)) + scans[0].corners.shape[1:], np.nan)
    for v, s in enumerate(scans):
        corners[v, np.searchsorted(frames, s.frames)] = s.corners
    return frames, corners


def _world_instant(frames: np.ndarray, corners: np.ndarray, names: list[str], world_frame: int) -> int:
    """The index in ``frames`` nearest ``world_frame`` (``--world-frame``), refused in one line
    unless two cameras or more see the board there."""
    instant = int(np.argmin(np.abs(frames - world_frame)))
    seen = [n for n, c in zip(names, corners[:, instant]) if np.isfinite(c).all(-1).sum() >= MIN_CORNERS]
    if len(seen) < 2:
        raise InputError("--world-frame", str(world_frame),
                         f"the board is found in frame {frames[instant]} (the nearest searched) by "
                         f"{', '.join(seen) or 'no camera'}: at least two cameras must see it")
    return instant


def _metadata(rig, board: Board, names: list[str], frames: np.ndarray, lenses: list, intrinsics) -> dict:
    """The ``[metadata]`` of a board calibration's Calib.toml: the residuals, the board, the world
    and where the intrinsics came from (each camera's residual and coverage when calibrated here)."""
    return {"adjusted": True, "error": round(float(np.mean(rig.rms_px)), 4),
            "method": f"{board.kind} (mvm rig calibrate --{board.kind})", "units": "m",
            "board": board.describe(), "cameras": names,
            "world": (f"the board at frame {int(frames[rig.world_view])} (origin on its first corner, z out of "
                      "its face)") if rig.world_view >= 0 else f"camera {names[0]}",
            "intrinsics": str(intrinsics) if intrinsics else "calibrated on the board",
            "intrinsics_rms_px": [round(lens.rms_px, 4) if lens else -1.0 for lens in lenses],
            "intrinsics_coverage": [round(lens.coverage, 3) if lens else -1.0 for lens in lenses],
            "residual_px": [round(float(r), 4) for r in rig.rms_px]}


def calibrate_rig_from_board(rig_dir: str | Path, out: str | Path, board: Board, intrinsics: str | Path | None = None,
                             world: str = "board", workers: int | None = None, progress=None,
                             fisheye: bool = False, world_frame: int | None = None) -> RigBoardCalibration:
    """Every camera's intrinsics (or those of ``intrinsics``) and pose from the board videos of
    ``rig_dir`` (module docstring); a full Calib.toml is written at ``out`` with each camera's
    residuals in ``[metadata]``. ``world``: ``"board"`` or ``"camera"``
    (:mod:`mvm.rig.board_calibration`); ``workers``: videos read at once (default: one per core);
    ``progress(video, frames done, total)``; ``fisheye``: calibrate OpenCV's fisheye lens;
    ``world_frame``: the frame of the extrinsics videos whose board is the world (the nearest
    frame searched; default: the first in which the most cameras see it). ``out`` being,
    holding or lying inside ``rig_dir/calibration`` or ``intrinsics`` is refused before any work
    (:func:`mvm.io.outputs.check_output_location`)."""
    rig_dir = Path(rig_dir)
    check_output_location(out, [rig_dir / CALIBRATION_DIR] + ([intrinsics] if intrinsics else []), replaced=False)
    intrinsic_sources, ext_sources = rig_videos(rig_dir)
    check_output_location(out, [*intrinsic_sources.values(), *ext_sources.values()], replaced=False)  # linked in
    names = list(ext_sources)
    if len(names) < 2:
        raise InputError(rig_dir / CALIBRATION_DIR, None, f"one camera ({names[0]}): a rig needs at least two")
    if board.symmetric:
        raise InputError("--board-size", f"{board.cols}x{board.rows}",
                         "a checkerboard with both counts even or both odd looks the same turned by 180°, so the "
                         "cameras cannot agree on its corners: use one even and one odd count (e.g. 7x6)")
    given = _given_intrinsics(Path(intrinsics), names) if intrinsics else None
    if given is not None:
        names = list(given.cameras.names)
    counts = {n: frame_count(ext_sources[n]) for n in names}                      # each header read once
    stride = scan_stride(counts.values())
    ext_scans = scan_all([(f"{n} extrinsics", ext_sources[n], stride, counts[n]) for n in names], board, workers,
                          progress)
    for name, s in zip(names, ext_scans):
        _check_found(s, ext_sources[name], name, board, "; the intrinsics alone: --intrinsics-only")
    if given is None:
        lenses = _calibrate_lenses(names, intrinsic_sources, ext_scans, ext_sources, board, workers, progress,
                                   fisheye)
        cameras = lens_cameras(names, lenses, ext_scans, fisheye)
    else:
        lenses = [None] * len(names)
        cameras = given.cameras
        for v, (name, s) in enumerate(zip(names, ext_scans)):
            if not np.allclose(cameras.size[v], s.size):
                raise InputError(ext_sources[name], None, f"camera {name}: {s.size[0]}x{s.size[1]} pixels, "
                                                          f"{intrinsics} says {cameras.size[v][0]:g}x"
                                                          f"{cameras.size[v][1]:g}")
    frames, corners = _corners_by_frame(ext_scans)
    instant = None if world_frame is None else _world_instant(frames, corners, names, world_frame)
    try:
        rig = calibrate_extrinsics(corners, cameras, board.object_points, world, instant)
    except CalibrationError as e:
        name = names[e.camera] if e.camera is not None else None
        raise InputError(ext_sources[name] if name else rig_dir / CALIBRATION_DIR, None,
                         (f"camera {name}: " if name else "") + e.problem) from None
    calibration = RigCalibration(rig.cameras, _metadata(rig, board, names, frames, lenses, intrinsics))
    out = Path(out)
    write_calib_toml(out, calibration)
    return RigBoardCalibration(calibration, lenses, rig, frames, out)
