"""The per-scene path against the rig path on the same detections, whole process.

    python benchmarks/rig_scene_path.py [--cameras 5] [--people 4] [--instants 300] [--repeats 1] [--workers N]

One synthetic capture (:func:`rig_speed.write_capture`: cameras on a ring, people walking,
detector errors as in the Panoptic evaluation) is written as a rig directory, and the same
2D poses, undistorted as the rig reader gives them, as one scene directory per instant (the
cameras as its views: ``sparse/`` and ``poses2d.json``). Then ``mvm rig reconstruct RIG`` and
``mvm reconstruct SCENE...`` (every scene in one command) each run in a fresh process, with
their defaults (``--workers N`` sets ``$MVM_WORKERS``, the processes either command may use);
the best wall and CPU seconds (children included) of ``--repeats`` runs are printed, and their
ratio (the per-scene path should stay within 3x of the rig path), and the mean stage timings
the scenes' ``poses3d.json`` record. BLAS is limited to one thread.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))

from rig_speed import write_capture  # noqa: E402

from mvm.core.scene import Poses2D  # noqa: E402
from mvm.io.scene_dir import write_scene  # noqa: E402
from mvm.parallel import available_workers  # noqa: E402
from mvm.rig.rigdir import read_rig  # noqa: E402


def rig_to_scenes(rig_dir: Path, out_dir: Path) -> list[Path]:
    """One scene directory per instant of ``rig_dir`` (named by frame number, the cameras as its
    views, the rig reader's undistorted 2D poses); returns their paths in frame order."""
    rig = read_rig(rig_dir)
    det, cameras = rig.detections, rig.calibration.cameras
    scenes = []
    for t, frame in enumerate(rig.frames):
        rows = det.instant == t
        poses = Poses2D(det.keypoints[rows], det.view[rows], det.ids[rows], det.score[rows])
        path = out_dir / f"frame_{int(frame):06d}"
        write_scene(path, cameras, poses, binary=False)
        scenes.append(path)
    return scenes


def run_mvm(args: list[str]) -> tuple[float, float]:
    """Wall and CPU seconds (user + system) of ``python -m mvm ARGS`` in a fresh process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "mvm", *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True)
    if run.returncode:
        raise SystemExit(f"mvm {args[0]} failed ({run.returncode}):\n{run.stderr[-2000:]}")
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cameras", type=int, default=5)
    parser.add_argument("--people", type=int, default=4)
    parser.add_argument("--instants", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--workers", type=int, default=None, help="MVM_WORKERS of both commands")
    args = parser.parse_args()
    if args.workers is not None:
        os.environ["MVM_WORKERS"] = str(args.workers)
    with tempfile.TemporaryDirectory() as tmp:
        rig_dir = Path(tmp) / "rig"
        write_capture(rig_dir, args.cameras, args.people, args.instants)
        scenes = rig_to_scenes(rig_dir, Path(tmp) / "scenes")
        print(f"{args.cameras} cameras, {args.people} people, {args.instants} instants; "
              f"{len(scenes)} scene directories; {available_workers()} worker(s)")
        results = {}
        # --force: a rerun with nothing changed keeps an up-to-date set (docs/reruns.md)
        for label, command in (("rig path: mvm rig reconstruct", ["rig", "reconstruct", str(rig_dir), "--force"]),
                               ("per-scene path: mvm reconstruct", ["reconstruct", *map(str, scenes)])):
            runs = [run_mvm(command) for _ in range(args.repeats)]
            wall, cpu = min(w for w, _ in runs), min(c for _, c in runs)
            results[label] = (wall, cpu)
            print(f"{label:34s} {wall:7.2f} s wall {cpu:7.2f} s CPU  "
                  f"({args.instants / wall:6.1f} instants/s wall; best of {args.repeats})")
        (rig_wall, rig_cpu), (scene_wall, scene_cpu) = results.values()
        print(f"per-scene / rig: {scene_wall / rig_wall:.2f}x wall, {scene_cpu / rig_cpu:.2f}x CPU (goal: under 3x)")
        print(stage_costs(scenes))


def stage_costs(scenes: list[Path]) -> str:
    """The mean of the stage timings each scene's ``poses3d.json`` records (the last run's;
    ``refinement_s`` is the scene's share of its batch's solve; writing is not timed there)."""
    totals: dict[str, float] = {}
    for scene in scenes:
        for stage, seconds in json.loads((scene / "mvm" / "poses3d.json").read_text())["timings_s"].items():
            totals[stage] = totals.get(stage, 0.0) + seconds
    return "per scene (ms): " + ", ".join(f"{stage[:-2]} {1000 * s / len(scenes):.1f}" for stage, s in totals.items())


if __name__ == "__main__":
    main()
