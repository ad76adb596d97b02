"""A real 4-camera capture from its raw material to 3D, every stage through the ``mvm`` command.

    python benchmarks/real_footage.py [--data ../shared/data/real_footage] [--work DIR]
        [--detections mvm|reference] [--skip-board]

The capture (``real_footage/``, its README): 4 portrait cameras of a motion-capture lab, one
person balancing on a platform, a bystander at the back seen by two cameras, 100 frames at
60 fps, checkerboard photos, the lab's marker-based calibration (Qualisys ``.qca``, the
reference) and a YOLO11n-pose ONNX model (AGPL-3.0: read from the data folder, never copied
into the repository).

The chain, each stage timed (whole ``mvm`` processes, imports included):

1. ``mvm rig detect --detector yolo-pose --model FILE.onnx`` (``--detections reference``: the
   model's detections by Ultralytics' own code, shipped with the data, instead);
2. ``mvm rig calibrate --convert Calib.qca.txt``: the lab's calibration;
3. ``mvm rig synchronize`` with it: offsets (the lab's cameras are synchronized to about 3 frames);
4. ``mvm rig calibrate --checkerboard --intrinsics-only`` on the board photos, then
   ``--from-people`` with those intrinsics, and with the lab's;
5. ``mvm rig reconstruct`` with each calibration (default settings), then ``mvm report``.

Printed per calibration: persons per instant, the tracks and their lengths, the main track's
limb-length std and jitter (:mod:`mvm.metrics.tracks`), the reprojection error; per
calibration from people: each camera centre's distance to the lab's after the best similarity.
Pose2Sim 0.10.49 on the same detections (multi-person, demo settings), as measured outside
mvm and stated in the data's README: 4.8 s, limb-length std 66 mm.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mvm.io.rig_poses3d import read_rig_poses3d
from mvm.metrics.poses import similarity_transform
from mvm.metrics.tracks import jitter, limb_length_std
from mvm.rig.rigdir import read_calibration

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real_footage"
CAMERAS = ("cam01", "cam02", "cam03", "cam04")


def mvm(*args: str) -> float:
    """Run ``mvm ARGS`` in a fresh process; its wall time in s (it must succeed)."""
    t = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "mvm", *map(str, args)], capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"mvm {' '.join(map(str, args))} failed ({done.returncode}):\n{done.stdout}{done.stderr}")
    return time.perf_counter() - t


def make_rig(data: Path, rig: Path, detections: str) -> None:
    """The rig folder a user makes: the videos, the board photos in Pose2Sim's layout, and with
    ``detections == "reference"`` Ultralytics' own detections as the poses."""
    (rig / "videos").mkdir(parents=True)
    for cam in CAMERAS:
        (rig / "videos" / f"{cam}.mp4").symlink_to(data / "videos" / f"{cam}.mp4")
    (rig / "calibration").mkdir()
    (rig / "calibration" / "intrinsics").symlink_to(data / "calibration" / "intrinsics")
    if detections == "reference":
        (rig / "pose").mkdir()
        for cam in CAMERAS:
            shutil.copy(data / "pose_ultralytics" / f"{cam}.json", rig / "pose" / f"{cam}.json")


def centre_errors_mm(calib: Path, reference: Path) -> np.ndarray:
    """Each camera centre's distance to the reference's, after the best similarity, in mm."""
    est = read_calibration(calib).cameras
    ref = read_calibration(reference).cameras
    index = [est.names.index(n) for n in ref.names]
    s, R, t = similarity_transform(est.centers[index], ref.centers)
    moved = s * est.centers[index] @ R.T + t
    return 1000 * np.linalg.norm(moved - ref.centers, axis=1)


def track_figures(out: Path) -> dict:
    """Persons per instant, tracks and lengths, the main track's limb-length std (mm) and jitter."""
    rec = read_rig_poses3d(out / "poses3d.jsonl")
    recap = json.loads((out / "recap.json").read_text())
    T = len(rec.frames)
    tracks, counts = np.unique(rec.track, return_counts=True)
    if not len(tracks):
        return {"instants": T, "persons_per_instant": {0: T}, "tracks": {}, "main_track_instants": 0,
                "limb_std_mm": np.nan, "limb_std_max_mm": np.nan, "jitter_mm_per_frame2": np.nan,
                "reprojection_error_px": np.nan}
    main = tracks[np.argmax(counts)]
    X = np.full((T, 17, 3), np.nan)
    rows = np.flatnonzero(rec.track == main)
    X[rec.instant[rows]] = rec.X[rows]
    per_instant = np.bincount(rec.instant, minlength=T)
    return {
        "instants": T,
        "persons_per_instant": {int(k): int(v) for k, v in zip(*np.unique(per_instant, return_counts=True))},
        "tracks": {int(k): int(v) for k, v in zip(tracks, counts)},
        "main_track_instants": int(counts.max()),
        "limb_std_mm": float(1000 * np.nanmean(limb_length_std(X))),
        "limb_std_max_mm": float(1000 * np.nanmax(limb_length_std(X))),
        "jitter_mm_per_frame2": 1000 * jitter(X),
        "reprojection_error_px": recap["reprojection_error_px"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--work", type=Path, default=None, help="Folder to work in (default: a temporary one).")
    parser.add_argument("--detections", choices=("mvm", "reference"), default="mvm")
    parser.add_argument("--skip-board", action="store_true", help="Leave out the board intrinsics.")
    args = parser.parse_args()
    if not args.data.is_dir():
        raise SystemExit(f"{args.data}: the real capture is not there (see shared/data/README.md)")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    work = args.work or Path(tempfile.mkdtemp(prefix="mvm-real-"))
    rig = work / "rig"
    if rig.exists():
        shutil.rmtree(rig)
    make_rig(args.data, rig, args.detections)
    times: dict[str, float] = {}
    lab = work / "lab.toml"
    if args.detections == "mvm":
        times["rig detect (yolo-pose)"] = mvm("rig", "detect", rig, "--detector", "yolo-pose",
                                               "--model", args.data / "models" / "yolo11n-pose.onnx")
    times["calibrate --convert (.qca)"] = mvm("rig", "calibrate", rig, "--convert",
                                              args.data / "calibration" / "Calib.qca.txt", "-o", lab)
    times["synchronize"] = mvm("rig", "synchronize", rig, "--calib", lab)
    sync = (rig / "sync.toml").read_text()
    calibrations = {"lab (.qca)": lab}
    times["calibrate --from-people (lab intrinsics)"] = mvm("rig", "calibrate", rig, "--from-people", "--intrinsics",
                                                            lab, "-o", work / "people_lab.toml")
    calibrations["people, lab intrinsics"] = work / "people_lab.toml"
    if not args.skip_board:
        times["calibrate --intrinsics-only (board photos)"] = mvm(
            "rig", "calibrate", rig, "--checkerboard", "--intrinsics-only", "--board-size", "4x7",
            "--square-size", "0.06", "-o", work / "board.toml")
        times["calibrate --from-people (board intrinsics)"] = mvm(
            "rig", "calibrate", rig, "--from-people", "--intrinsics", work / "board.toml", "-o",
            work / "people_board.toml")
        calibrations["people, board intrinsics"] = work / "people_board.toml"
    figures = {}
    for i, (name, calib) in enumerate(calibrations.items()):
        out = rig / "mvm" if calib == lab else work / f"out{i}"      # the lab's in the rig, for the report
        times[f"reconstruct ({name})"] = mvm("rig", "reconstruct", rig, "--calib", calib, "-o", out, "--force")
        figures[name] = track_figures(out)
        if calib != lab:
            figures[name]["centre_error_mm"] = centre_errors_mm(calib, lab).round(1).tolist()
    times["report (lab calibration)"] = mvm("report", rig)

    print(f"# real capture: {args.detections} detections, work folder {work}")
    print(f"sync.toml:\n{sync.strip()}")
    print("\n| calibration | persons per instant | tracks (instants) | main track "
          "| limb-length std mm (mean / worst bone) | jitter mm/frame² | reprojection px "
          "| camera centres mm (after similarity) |")
    print("|---|---|---|---|---|---|---|---|")
    for name, f in figures.items():
        centres = f.get("centre_error_mm")
        centre_text = (f"{np.mean(centres):.0f} mean, {np.max(centres):.0f} worst "
                       f"({', '.join(f'{c:.0f}' for c in centres)})" if centres else "(reference)")
        print(f"| {name} | {f['persons_per_instant']} | {f['tracks']} | {f['main_track_instants']} / {f['instants']} "
              f"| {f['limb_std_mm']:.1f} / {f['limb_std_max_mm']:.1f} | {f['jitter_mm_per_frame2']:.2f} "
              f"| {f['reprojection_error_px']:.1f} | {centre_text} |")
    print("\n| stage | s |\n|---|---|")
    for stage, seconds in times.items():
        print(f"| {stage} | {seconds:.1f} |")
    print(f"| whole chain | {sum(times.values()):.1f} |")
    print("\nPose2Sim 0.10.49 on the reference detections (outside mvm, the data's README): 4.8 s, "
          "limb-length std 66 mm, the person kept over the 100 instants.")


if __name__ == "__main__":
    main()
