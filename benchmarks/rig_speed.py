"""Instants per second of the rig pipeline, whole process: reading the OpenPose files,
reconstruction, tracking, the rigid-skeleton refinement, smoothing, completion and writing.

    python benchmarks/rig_speed.py [--cameras 5] [--people 4] [--instants 300] [--repeats 3]

Synthetic capture written as a rig directory (Calib.toml + one OpenPose JSON per camera and
frame): cameras on a ring, people walking, detector errors as in the Panoptic evaluation.
Each configuration runs ``--repeats`` times; the best wall time and the best CPU time of the
process are printed (on a machine shared with other work the CPU time is the steadier figure).
Then one run of the ``mvm rig reconstruct`` command in a fresh process (imports included).
BLAS is limited to one thread.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from mvm.core.config import Config  # noqa: E402
from mvm.io.calib_toml import RigCalibration, write_calib_toml  # noqa: E402
from mvm.io.openpose import BODY25_TO_COCO17  # noqa: E402
from mvm.rig.options import RigOptions  # noqa: E402
from mvm.rig.pipeline import reconstruct_rig  # noqa: E402
from mvm.sim.rig import detect_views, ring_cameras, walking_people  # noqa: E402


def write_capture(root: Path, cameras: int, people: int, instants: int, seed: int = 0) -> None:
    rig = ring_cameras(cameras)
    rng = np.random.default_rng(seed)
    truth = walking_people(people, instants, rng)
    write_calib_toml(root / "Calib.toml", RigCalibration(rig, tuple(np.zeros(4) for _ in range(cameras)),
                                                         np.zeros(cameras, bool)))
    for t in range(instants):
        kp, cam, _ = detect_views(rig, truth[t], rng)
        for v, name in enumerate(rig.names):
            folder = root / "pose" / name
            folder.mkdir(parents=True, exist_ok=True)
            found = []
            for k in kp[cam == v]:
                body25 = np.zeros((25, 3))
                body25[BODY25_TO_COCO17] = k
                found.append({"person_id": [-1], "pose_keypoints_2d": body25.reshape(-1).tolist()})
            (folder / f"{name}_{t:012d}_keypoints.json").write_text(json.dumps({"people": found}))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--cameras", type=int, default=5)
    parser.add_argument("--people", type=int, default=4)
    parser.add_argument("--instants", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "rig"
        write_capture(root, args.cameras, args.people, args.instants)
        print(f"{args.cameras} cameras, {args.people} people, {args.instants} instants")
        runs = [("refinement off, no completion", Config(refine=False), RigOptions(complete=False, smoothing="none")),
                ("refinement + completion (defaults)", Config(), RigOptions())]
        for label, config, options in runs:
            wall, cpu = [], []
            for _ in range(args.repeats):
                t0, c0 = time.perf_counter(), time.process_time()
                result = reconstruct_rig(root, config, options)
                wall.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
            phases = ", ".join(f"{k} {v:.2f}" for k, v in result.timings.items())
            print(f"{label}: {args.instants / min(wall):6.1f} instants/s wall, {args.instants / min(cpu):6.1f} "
                  f"instants/s CPU (best of {args.repeats}); last run's phases (wall s): {phases}")
        t0 = time.perf_counter()
        run = subprocess.run([sys.executable, "-c", "import resource, sys; from mvm.cli.main import main\n"
                              "try:\n    main(sys.argv[1:], standalone_mode=False)\nfinally:\n"
                              "    r = resource.getrusage(resource.RUSAGE_SELF)\n"
                              "    print('cpu', r.ru_utime + r.ru_stime, file=sys.stderr)",
                              "rig", "reconstruct", str(root)], capture_output=True, text=True)
        wall = time.perf_counter() - t0
        cpu = float(run.stderr.strip().splitlines()[-1].split()[1])
        print(f"`mvm rig reconstruct` in a fresh process: {args.instants / wall:.1f} instants/s wall, "
              f"{args.instants / cpu:.1f} instants/s CPU ({wall:.1f} s, {cpu:.1f} s CPU)")


if __name__ == "__main__":
    main()
