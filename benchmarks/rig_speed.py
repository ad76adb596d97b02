"""Instants per second of the rig pipeline (one core), refinement off and on.

    python benchmarks/rig_speed.py [--cameras 5] [--people 4] [--instants 300]

Synthetic capture: cameras on a ring, people walking, detector errors as in the Panoptic
evaluation. Times `reconstruct_instants` only (reading files excluded); BLAS limited to one thread.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from mvm.core.config import Config
from mvm.eval.metrics import match_persons, pose_errors
from mvm.rig.instants import reconstruct_instants, rig_poses
from mvm.sim.rig import detect_views, pose_scores, ring_cameras, walking_people


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--cameras", type=int, default=5)
    parser.add_argument("--people", type=int, default=4)
    parser.add_argument("--instants", type=int, default=300)
    parser.add_argument("--batch-size", type=int, default=64)
    args = parser.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    rng = np.random.default_rng(0)
    cameras = ring_cameras(args.cameras)
    truth = walking_people(args.people, args.instants, rng)
    kps, cams, inst = [], [], []
    for t in range(args.instants):
        k, c, _ = detect_views(cameras, truth[t], rng)
        kps.append(k), cams.append(c), inst.append(np.full(len(c), t))
    kp = np.concatenate(kps)
    det = rig_poses(kp, np.concatenate(inst), np.concatenate(cams), pose_scores(kp))
    print(f"{args.cameras} cameras, {args.people} people, {args.instants} instants, {len(det)} 2D poses")
    for refine in (False, True):
        reconstruct_instants(cameras, det.subset(np.flatnonzero(det.instant < 8)), Config(refine=refine))  # warm-up
        t0 = time.perf_counter()
        persons = reconstruct_instants(cameras, det, Config(refine=refine), batch_size=args.batch_size)
        seconds = time.perf_counter() - t0
        errors = [pose_errors(persons.X[persons.instant == t], truth[t],
                              match_persons(persons.X[persons.instant == t], truth[t], 0.5))["mpjpe"]
                  for t in range(args.instants)]
        print(f"refine={'on ' if refine else 'off'}: {args.instants / seconds:7.1f} instants/s "
              f"({seconds:.2f} s), MPJPE {1000 * np.nanmean(errors):.1f} mm")


if __name__ == "__main__":
    main()
