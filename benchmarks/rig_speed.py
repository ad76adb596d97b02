"""Instants per second of the rig pipeline, whole process: reading the OpenPose files,
reconstruction, tracking, the rigid-skeleton refinement, smoothing, completion and writing.

    python benchmarks/rig_speed.py [--cameras 5] [--people 4] [--instants 300] [--repeats 3]

Synthetic capture written as a rig directory (Calib.toml + one OpenPose JSON per camera and
frame): cameras on a ring, people walking, detector errors as in the Panoptic evaluation.
Each configuration runs ``--repeats`` times; the best wall time and the best CPU time of the
process and its workers are printed (on a machine shared with other work the CPU time is the
steadier figure).
Then the ``mvm rig reconstruct`` command in fresh processes (imports included; best of
``--repeats``). BLAS is limited to one thread; the pipeline uses one worker process per core
(``mvm.parallel``) unless told otherwise.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
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
from mvm.parallel import available_workers  # noqa: E402
from mvm.rig.options import RigOptions  # noqa: E402
from mvm.rig.reconstruct_rig import reconstruct_rig  # noqa: E402
from mvm.sim.rig import detect_views, ring_cameras, walking_people  # noqa: E402


def write_capture(root: Path, cameras: int, people: int, instants: int, seed: int = 0) -> None:
    rig = ring_cameras(cameras)
    rng = np.random.default_rng(seed)
    truth = walking_people(people, instants, rng)
    write_calib_toml(root / "Calib.toml",
                     RigCalibration(dataclasses.replace(rig, distortion=tuple(np.zeros(4) for _ in range(cameras)))))
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
        workers = available_workers()
        runs = [("refinement off, no completion", Config(refine=False, complete=False), RigOptions(smoothing="none")),
                ("refinement + completion, 1 worker", Config(), RigOptions(workers=1)),
                (f"refinement + completion (defaults: {workers} workers)", Config(), RigOptions())]
        for label, config, options in runs:
            wall, cpu = [], []
            for _ in range(args.repeats):
                t0, c0 = time.perf_counter(), cpu_seconds()
                result = reconstruct_rig(root, config, options)
                wall.append(time.perf_counter() - t0)
                cpu.append(cpu_seconds() - c0)
            phases = ", ".join(f"{k} {v:.2f}" for k, v in result.timings.items())
            print(f"{label}: {args.instants / min(wall):6.1f} instants/s wall, {args.instants / min(cpu):6.1f} "
                  f"instants/s CPU (best of {args.repeats}); last run's phases (wall s): {phases}")
        wall, cpu = [], []
        for _ in range(args.repeats):
            t0, c0 = time.perf_counter(), cpu_seconds()
            # --force: a rerun with nothing changed keeps the set up to date (docs/reruns.md) and
            # would time the check of the records, not the reconstruction
            subprocess.run([sys.executable, "-m", "mvm", "rig", "reconstruct", str(root), "--force"], check=True,
                           capture_output=True)
            wall.append(time.perf_counter() - t0)
            cpu.append(cpu_seconds() - c0)
        print(f"`mvm rig reconstruct` in a fresh process: {args.instants / min(wall):.1f} instants/s wall "
              f"({min(wall):.2f} s), {min(cpu):.2f} s CPU over all processes (best of {args.repeats})")


def cpu_seconds() -> float:
    """CPU seconds of this process and of the children it has waited for (the worker processes)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


if __name__ == "__main__":
    main()
