"""A rig calibrated with a board, against the truth, on rendered calibration videos.

    python benchmarks/board_calibration.py [--cameras 3] [--seed 0]

The videos are those of the tests (``tests/board_scenes.py``): cameras on a ring 3 m from the
middle, each its own focal length, principal point and lens, 640x480 mp4; ``intrinsics/``
shows the board held in front of each camera (20 frames), ``extrinsics/`` the board moved and
tilted about on the floor (24 frames). Cases: a 7x6 checkerboard of 70 mm squares; a 6x5
ChArUco board of 100 mm squares; the checkerboard with fisheye lenses (wide-angle cameras, 1.7 m
away); one still image of the checkerboard on the floor per camera, the intrinsics given
(Pose2Sim's board method). Each runs ``mvm rig calibrate`` and compares the Calib.toml written with
the truth: the worst focal-length and principal-point errors, camera-centre and rotation errors
(world frame: the board of the first frame), the intrinsics RMS and the residuals, CPU seconds.
"""
from __future__ import annotations

import argparse
import resource
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

TESTS = Path(__file__).resolve().parents[1] / "tests"
sys.path[:0] = [str(TESTS)]

from click.testing import CliRunner  # noqa: E402

from board_scenes import (  # noqa: E402
    CHARUCO,
    CHECKERBOARD,
    FIRST_CORNER,
    ring_cameras,
    write_board_rig,
    write_still_board,
    write_true_calibration,
)
from mvm.cli.rig import rig  # noqa: E402
from mvm.io.calib_toml import read_calib_toml  # noqa: E402


def _cpu() -> float:
    return sum(resource.getrusage(who).ru_utime + resource.getrusage(who).ru_stime
               for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))


def run_case(root: Path, case: str, n: int, seed: int) -> dict:
    board = CHARUCO if case == "charuco" else CHECKERBOARD
    extra = []
    if case == "still":
        cams = ring_cameras(n, seed)
        names = [f"cam_{v + 1:02d}" for v in range(n)]
        write_still_board([root / "calibration" / "extrinsics" / f"{n}.png" for n in names], CHECKERBOARD, cams)
        extra = ["--intrinsics", str(write_true_calibration(root.parent / "intrinsics.toml", cams, names))]
    else:
        truth = write_board_rig(root, board, n, seed=seed, fisheye=case == "fisheye")
        cams = truth.cameras
        extra = ["--fisheye"] if case == "fisheye" else []
    args = ["calibrate", str(root), f"--{board.kind}", "--board-size", f"{board.cols}x{board.rows}",
            "--square-size", str(board.square_m), "-o", str(root / "out.toml"), *extra]
    if board.kind == "charuco":
        args += ["--marker-size", str(board.marker_m)]
    cpu = _cpu()
    result = CliRunner().invoke(rig, args)
    cpu = _cpu() - cpu
    if result.exit_code:
        raise SystemExit(f"{case}: {result.output}")
    found = read_calib_toml(root / "out.toml")
    K = found.cameras.K
    rotation = [np.degrees(np.linalg.norm(cv2.Rodrigues(found.cameras.R[v] @ c.R.T)[0])) for v, c in enumerate(cams)]
    return {"focal %": 100 * max(abs(K[v, 0, 0] / c.K[0, 0] - 1) for v, c in enumerate(cams)),
            "principal px": max(np.abs(K[v, :2, 2] - c.K[:2, 2]).max() for v, c in enumerate(cams)),
            "centre mm": 1000 * max(np.linalg.norm(found.cameras.centers[v] - (c.centre - FIRST_CORNER))
                                    for v, c in enumerate(cams)),
            "rotation deg": max(rotation),
            "intrinsics RMS px": max(found.metadata["intrinsics_rms_px"]),
            "residual px": max(found.metadata["residual_px"]), "cpu s": cpu}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cameras", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    columns = ("focal %", "principal px", "centre mm", "rotation deg", "intrinsics RMS px", "residual px", "cpu s")
    print(f"## Board calibration against the truth ({args.cameras} cameras, worst camera)\n")
    print("| case | " + " | ".join(columns) + " |")
    print("|---" * (len(columns) + 1) + "|")
    for case in ("checkerboard", "charuco", "fisheye", "still"):
        with tempfile.TemporaryDirectory() as folder:
            r = run_case(Path(folder) / "rig", case, args.cameras, args.seed)
        given = case == "still"
        print(f"| {case} | " + " | ".join("given" if given and c in ("focal %", "principal px", "intrinsics RMS px")
                                         else f"{r[c]:.3f}" for c in columns) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
