"""Time of the refinement on the rig benchmark's persons, and of one scene's refinement.

    python benchmarks/refine_timing.py [--repeats 5]

The capture of ``rig_speed.py`` (5 cameras on a ring, 4 people walking, 300 instants,
detector errors as in the Panoptic evaluation) is read and reconstructed per instant without
refinement, and its persons tracked, as ``mvm rig reconstruct`` does; then

- ``refine_tracks``: every person refined once against its keypoints, the pose prior and its
  track's bone lengths (one :func:`mvm.core.refine.refine_poses` call on all of them);
- per scene: :func:`~mvm.core.refine.refine_poses` of one instant's persons (reprojection and
  the prior, the per-scene path's settings), over the first 60 instants.

Best of ``--repeats`` CPU seconds (the steadier figure on a machine shared with other work)
and wall seconds; the objective after refinement, and the persons solved per
Levenberg-Marquardt step summed over steps, in units of all persons. BLAS on one thread.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from rig_speed import write_capture

from mvm.core import refine
from mvm.core.image_units import in_person_sizes
from mvm.core.prior import shipped_prior
from mvm.rig.instants import reconstruct_instants
from mvm.rig.options import RigOptions
from mvm.rig.reconstruct_rig import instants_config, rig_config
from mvm.rig.rigdir import read_rig
from mvm.rig.skeleton import (
    OUTER_ITERATIONS,
    TOLERANCE,
    detection_sizes,
    observations,
    refine_tracks,
    track_bone_lengths,
)
from mvm.rig.tracking import track_persons


def best_of(repeats: int, run) -> tuple[float, float, object]:
    """Best CPU and wall seconds of ``repeats`` calls of ``run()``, and its last result."""
    cpu, wall = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        out = run()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    return min(cpu), min(wall), out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    config, options, prior = rig_config(), RigOptions(), shipped_prior()
    with tempfile.TemporaryDirectory() as tmp:
        write_capture(Path(tmp) / "rig", 5, 4, 300)
        rig = read_rig(Path(tmp) / "rig")
    cameras, detections = rig.calibration.cameras, rig.detections
    persons = reconstruct_instants(cameras, detections, instants_config(config), prior, options.batch_size)
    track = track_persons(persons.X, persons.instant, options.max_link_distance_m / options.metres_per_unit,
                          options.max_gap, options.min_link_joints).track
    solved = []
    solve = refine.spd_solve

    def counting(A, b):
        solved[-1] += len(A)
        return solve(A, b)

    refine.spd_solve = counting
    with np.errstate(all="ignore"):
        solved.append(0)
        refine_tracks(persons, track, detections, cameras, config, prior, options.bone_weight)   # warm caches
        cpu, wall, _ = best_of(args.repeats, lambda: refine_tracks(persons, track, detections, cameras, config,
                                                                   prior, options.bone_weight))
        xy, conf, P, used = observations(persons, detections, cameras, config.keypoint_threshold)
        xy, P = in_person_sizes(xy, P, detection_sizes(persons, detections, config.keypoint_threshold))
        solved.append(0)                                         # refine_tracks' own solve, counted once
        whole = refine.refine_poses(persons.X, xy, conf, P, used, prior, config.prior_weight, config.robust_scale,
                                    config.refine_max_iterations, bone_lengths=track_bone_lengths(persons.X, track),
                                    bone_weight=options.bone_weight, outer_iterations=OUTER_ITERATIONS,
                                    tolerance=TOLERANCE)
        print(f"refine_tracks, {len(persons)} persons: {cpu:.3f} s CPU, {wall:.3f} s wall (best of {args.repeats}); "
              f"objective {whole.cost_before:.6g} -> {whole.cost_after:.9g}; "
              f"persons solved {solved[-1] / len(persons):.2f} x all")
        scenes = [np.flatnonzero(persons.instant == t) for t in range(60)]
        calls = [(persons.X[s], xy[s], conf[s], P[s], used[s]) for s in scenes if len(s)]

        def per_scene():
            return [refine.refine_poses(*c, prior, config.prior_weight, config.robust_scale,
                                        config.refine_max_iterations) for c in calls]

        per_scene()
        cpu, wall, results = best_of(args.repeats, per_scene)
        print(f"refine_poses per scene ({np.mean([len(c[0]) for c in calls]):.1f} persons, {len(calls)} scenes): "
              f"{1000 * cpu / len(calls):.2f} ms CPU, {1000 * wall / len(calls):.2f} ms wall (best of {args.repeats}); "
              f"objective {sum(r.cost_after for r in results):.9g}")
    refine.spd_solve = solve


if __name__ == "__main__":
    main()
