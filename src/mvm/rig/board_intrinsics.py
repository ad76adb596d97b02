"""Each camera's intrinsics alone from videos or photos of a board
(:func:`~mvm.rig.board_calibration.calibrate_intrinsics` on the board found by
:mod:`mvm.rig.board_videos`), written as a Calib.toml of intrinsics and lens distortion only (no
``rotation`` nor ``translation``: :func:`mvm.io.calib_toml.read_calib_toml` reads it with
``extrinsics=False``, as ``mvm rig calibrate --from-people --intrinsics FILE`` does).

::

    RIG_DIR/calibration/
      intrinsics/<camera>.<ext>        a video of the board moved in front of the camera, or
      intrinsics/<camera>/             photos of it (Pose2Sim: int_<camera>_img/), or a folder
                                       holding one video (Pose2Sim: int_<camera>_vid/)
      <camera>.<ext>                   or, without intrinsics/, the videos right in calibration/
                                       (anipose: calibration/calib-<camera>.mp4)

The cameras are calibrated one by one, so one camera is enough, and the board may look the same
turned by 180° (each view's corners are matched to the board on their own).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration, write_calib_toml
from mvm.io.layout import CALIBRATION_DIR, INTRINSICS_DIR
from mvm.io.outputs import check_output_location
from mvm.rig.board_calibration import Intrinsics
from mvm.rig.board_videos import (
    BoardScan,
    calibration_sources,
    camera_lens,
    frame_count,
    lens_cameras,
    scan_all,
    scan_stride,
)
from mvm.rig.boards import Board


@dataclass
class BoardIntrinsics:
    """Intrinsics from a board: ``calibration`` (written at ``path``; ``R`` and ``t`` NaN), each
    camera's ``lenses`` (:class:`~mvm.rig.board_calibration.Intrinsics`), ``sources`` (camera ->
    its video, photo folder or folder holding a video) and ``scans`` (the board found in each)."""

    calibration: RigCalibration
    lenses: list[Intrinsics]
    sources: dict[str, Path]
    scans: list[BoardScan]
    path: Path


def intrinsic_sources(rig_dir: Path) -> dict[str, Path]:
    """``{camera: source}`` of ``rig_dir/calibration/intrinsics``, else of ``rig_dir/calibration``
    (module docstring); none raises :class:`InputError`."""
    root = rig_dir / CALIBRATION_DIR
    sources = calibration_sources(root / INTRINSICS_DIR) or calibration_sources(root)
    if not sources:
        raise InputError(root, None, "no calibration videos or photos: expected calibration/intrinsics/<camera>.<ext> "
                                     "or calibration/intrinsics/<camera>/ with images (Pose2Sim: int_<camera>_img/), "
                                     "or calibration/<camera>.<ext> (anipose)")
    return sources


def calibrate_intrinsics_from_board(rig_dir: str | Path, out: str | Path, board: Board, workers: int | None = None,
                                    progress=None, fisheye: bool = False) -> BoardIntrinsics:
    """Every camera's intrinsics and lens from its video or photos of ``board`` in ``rig_dir``
    (module docstring); a Calib.toml of intrinsics only is written at ``out``, each camera's
    reprojection RMS and board count in ``[metadata]``. ``workers``: sources read at once
    (default: one per core); ``progress(camera, frames done, total)``; ``fisheye``: OpenCV's
    fisheye lens. ``out`` being or lying inside ``rig_dir/calibration`` or a source (a linked
    folder of photos too) is refused before any work (:func:`mvm.io.outputs.check_output_location`)."""
    rig_dir = Path(rig_dir)
    sources = intrinsic_sources(rig_dir)
    check_output_location(out, [rig_dir / CALIBRATION_DIR, *sources.values()], replaced=False)   # linked ones too
    names = list(sources)
    counts = {n: frame_count(sources[n]) for n in names}
    scans = scan_all([(n, sources[n], scan_stride([counts[n]]), counts[n]) for n in names], board, workers, progress)
    lenses = [camera_lens(s, sources[n], n, board, fisheye) for n, s in zip(names, scans)]
    metadata = {"adjusted": False, "error": round(float(np.mean([lens.rms_px for lens in lenses])), 4),
                "method": f"{board.kind} (mvm rig calibrate --{board.kind} --intrinsics-only)",
                "board": board.describe(), "cameras": names, "intrinsics": "calibrated on the board",
                "extrinsics": "none (intrinsics only)",
                "board_found": [s.found for s in scans], "board_searched": [len(s.frames) for s in scans],
                "intrinsics_views": [len(lens.views) for lens in lenses],
                "intrinsics_rms_px": [round(lens.rms_px, 4) for lens in lenses],
                "intrinsics_coverage": [round(lens.coverage, 3) for lens in lenses]}
    calibration = RigCalibration(lens_cameras(names, lenses, scans, fisheye), metadata)
    out = Path(out)
    write_calib_toml(out, calibration)
    return BoardIntrinsics(calibration, lenses, sources, scans, out)
