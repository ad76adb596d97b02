"""The rig evaluation tables on the real CMU Panoptic sample (docs/results.md, "Synchronized camera rigs").

    python benchmarks/rig_panoptic.py [--seeds 3] [--refine] [--skip-cameras]

Real 31-camera HD calibration (with lens distortion) and real 3D poses of three people over
20 instants; 2D detections simulated from them, distorted, then undistorted by the pipeline.
Cameras spread around the dome.

Table 1 (per instant, cameras 5 / 10 / 31): the default detector error model (noise 1 % of the
person's image height, occlusion, 3 % dropped joints, 1 % swaps, 2 % outliers, 0.1 false poses
per view).

Table 2 (tracks and completion, 5 cameras): the crowd benchmark's harsher detector (noise 1.5 %,
5 % dropped joints, 2 % left/right swaps, 1 % outlier joints, false poses 10 % of the true ones), the
rig's time steps before (tracking by the nearest last pose over any shared joint, no smoothing,
missing joints left empty) and after (motion-predicted tracks gated over 4+ joints, Butterworth
at the default cut-off, completion by interpolation then the pose prior). PCP counts a limb with
a missing end as wrong; MPJPE is over the joints each estimate has.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from mvm.core.completion import FLAG_NAMES, MISSING, OBSERVED
from mvm.core.config import Config
from mvm.eval.panoptic import evaluate, load_sample, simulate_detections, spread_cameras
from mvm.metrics.mocap_scores import pcp
from mvm.metrics.poses import match_persons, pose_errors
from mvm.rig.instants import reconstruct_instants
from mvm.rig.options import RigOptions
from mvm.rig.reconstruct_rig import completion_prior, instants_config, rig_config, track_and_complete
from mvm.rig.tracking import identity_switches, track_persons
from mvm.sim.detector import DetectorErrors
from mvm.sim.simulate import PRESETS

SEQUENCE = Path(__file__).resolve().parents[2] / "shared" / "data" / "panoptic" / "160906_band1"
#: The crowd benchmark's detector (``sim.simulate.PRESETS["crowd"]``): false poses 10 % of the
#: true ones, here 0.3 per view for the sample's three people.
CROWD_ERRORS = DetectorErrors(**{k: PRESETS["crowd"][k] for k in ("noise", "dropout", "swap_prob",
                                                                   "outlier_joint_prob")},
                              false_pose_rate=PRESETS["crowd"]["false_pose_rate"] / PRESETS["crowd"]["people"] * 3)
#: A person is the true person of smallest MPJPE within this distance (metres).
MATCH_M = 0.5


def _before(persons, options: RigOptions):
    """The rig's earlier time steps: nearest last pose over any shared joint, nothing else."""
    tracking = track_persons(persons.X, persons.instant, options.max_link_distance_m / options.metres_per_unit,
                             options.max_gap, min_joints=1, velocity_weight=0.0)
    flags = np.where(np.isfinite(persons.X).all(-1), OBSERVED, MISSING)
    return tracking, persons.X, flags


def temporal_table(sample, seeds: int, config: Config, n_cameras: int = 5) -> dict:
    index = spread_cameras(sample.calibration.cameras, n_cameras)
    cameras = sample.calibration.cameras.subset(index)
    options = RigOptions(frame_rate=30.0)
    rig = rig_config(config)                      # "after": the rig driver's settings
    prior = completion_prior(rig)
    rows = {}
    for name in ("before", "after"):
        estimates, truths, ids, errors, flags_all, switches, per_person, seconds = [], [], [], [], [], 0, [], 0.0
        by_flag = {f: [] for f in range(len(FLAG_NAMES))}
        for seed in range(seeds):
            det = simulate_detections(sample, index, seed, CROWD_ERRORS)
            t0 = time.perf_counter()
            if name == "before":
                persons = reconstruct_instants(cameras, det, config, prior)
                tracking, X, flags = _before(persons, options)
            else:
                persons = reconstruct_instants(cameras, det, instants_config(rig), prior)
                tracking, persons, X, flags = track_and_complete(persons, options, prior, rig, det, cameras)
            seconds += time.perf_counter() - t0
            truth_id = np.full(len(X), -1)
            for t, X_true in enumerate(sample.poses):
                rows_t = np.flatnonzero(persons.instant == t)
                pairs = match_persons(X[rows_t], X_true, MATCH_M)
                for p, g in pairs:
                    truth_id[rows_t[p]] = sample.ids[t][g]
                    d = np.linalg.norm(X[rows_t[p]] - X_true[g], axis=-1)
                    for f in range(1, len(FLAG_NAMES)):
                        by_flag[f] += d[(np.asarray(flags)[rows_t[p]] == f) & np.isfinite(d)].tolist()
                e = pose_errors(X[rows_t], X_true, pairs)
                if e["evaluated_persons"]:
                    errors += [e["mpjpe"]] * e["evaluated_persons"]
                estimates.append(X[rows_t])
                truths.append(X_true)
                ids.append(sample.ids[t])
            flags_all.append(np.asarray(flags)[truth_id >= 0])
            s = identity_switches(tracking.track, truth_id, persons.instant)
            switches += s["switches"]
            per_person.append(s["tracks_per_person"])
        counts = np.bincount(np.concatenate(flags_all).astype(int).ravel(), minlength=len(FLAG_NAMES))
        rows[name] = {"pcp": pcp(estimates, truths, ids)["average"], "mpjpe_mm": 1000 * float(np.mean(errors)),
                      "flags": counts / counts.sum(), "switches": switches / seeds,
                      "error_by_flag_mm": {f: 1000 * float(np.mean(v)) if v else float("nan")
                                           for f, v in by_flag.items()},
                      "tracks_per_person": float(np.mean(per_person)),
                      "instants_per_s": len(sample.poses) * seeds / seconds}
    return rows


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--refine", action="store_true", help="Table 1 with refinement (Table 2 always refines).")
    parser.add_argument("--skip-cameras", action="store_true", help="Only Table 2.")
    parser.add_argument("--sequence", type=Path, default=SEQUENCE)
    args = parser.parse_args()
    if not args.sequence.is_dir():
        print(f"Panoptic sample absent: {args.sequence}", file=sys.stderr)
        return 2
    sample = load_sample(args.sequence)
    if not args.skip_cameras:
        config = Config(refine=args.refine)
        print("| cameras | MPJPE mm | PA-MPJPE mm | PCP | persons found | AP@25 | AP@50 | AP@150 | instants/s |")
        print("|---|---|---|---|---|---|---|---|---|")
        for n in (5, 10, 31):
            r = evaluate(sample, n, config, seeds=args.seeds)
            print(f"| {n} | {r['mpjpe_mm']:.1f} | {r['pa_mpjpe_mm']:.1f} | {r['pcp']:.3f} | {r['found']:.3f} | "
                  f"{r['AP@25']:.3f} | {r['AP@50']:.3f} | {r['AP@150']:.3f} | {r['instants_per_s']:.0f} |")
        print()
    rows = temporal_table(sample, args.seeds, Config())
    print(f"5 cameras, crowd detector errors, {args.seeds} seeds, {len(sample.poses)} instants, 3 people")
    print("| time steps | PCP | MPJPE mm | joints observed / interpolated / inferred / missing | "
          "error mm observed / interpolated / inferred | tracks per person | id switches | instants/s |")
    print("|---|---|---|---|---|---|---|---|")
    for name, r in rows.items():
        f, e = r["flags"], r["error_by_flag_mm"]
        print(f"| {name} | {r['pcp']:.3f} | {r['mpjpe_mm']:.1f} | {f[1]:.1%} / {f[2]:.1%} / {f[3]:.1%} / {f[0]:.1%} | "
              f"{e[1]:.1f} / {e[2]:.1f} / {e[3]:.1f} | {r['tracks_per_person']:.2f} | {r['switches']:.1f} | "
              f"{r['instants_per_s']:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
