"""A rig calibrated and synchronized from its people, on the real CMU Panoptic sample.

    python benchmarks/rig_calibration.py [--cameras 5 10] [--seeds 3] [--focal-error 0.05] [--sequence PATH]

Real HD cameras of the dome (spread around it) and real 3D poses of three people over 20
instants; 2D detections simulated from them with the detector's default errors (noise 1 % of
the person's image height, occlusion, 3 % dropped joints, 1 % swaps, 2 % outlier joints, 0.1
false poses per view), distorted and undistorted as a real pipeline does.

Calibration (:func:`mvm.eval.rig_from_people.calibration_check`): only the intrinsics are
given; every camera's rotation and position is found from the people. After the similarity
that maps the estimated camera centres onto the true ones: the mean camera-centre error
(target: within 5 cm), the scale error of the bone-length metres, the reprojection residual,
and the PCP of the reconstruction with the estimated calibration beside the true one's (target:
within one point).

Focal lengths given ``--focal-error`` off (alternately up and down, camera 0 up), calibrated
without and with ``refine_focal`` (the bundle adjustment adjusts them): the focal lengths found,
the camera centres and PCP as above.

Synchronization (:func:`mvm.eval.rig_from_people.sync_check`): offsets of up to 3 frames each
way on 5 cameras (the sample has 20 instants), recovered with the true calibration's epipolar
geometry and with the people's alone; PCP with the true offsets, the found ones and none.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from mvm.eval.panoptic import load_sample
from mvm.eval.rig_from_people import calibration_check, sync_check

SEQUENCE = Path(__file__).resolve().parents[2] / "shared" / "data" / "panoptic" / "160906_band1"
OFFSETS = np.array([0, 3, -2, 2, -3])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cameras", type=int, nargs="+", default=[5, 10])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--focal-error", type=float, default=0.05, help="0: skip the focal-length check")
    parser.add_argument("--sequence", type=Path, default=SEQUENCE)
    args = parser.parse_args(argv)
    if not args.sequence.is_dir():
        print(f"Panoptic sample absent: {args.sequence}", file=sys.stderr)
        return 1
    sample = load_sample(args.sequence)

    print("## Calibration from people (Panoptic dome, intrinsics only)\n")
    print("| cameras | seed | mean centre error (cm) | worst (cm) | scale error | residual px | "
          "PCP true calib. | PCP estimated | seconds |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in args.cameras:
        rows = []
        for seed in range(args.seeds):
            r = calibration_check(sample, n, seed)
            rows.append(r)
            print(f"| {n} | {seed} | {100 * r['mean_centre_error_m']:.2f} | {100 * max(r['centre_error_m']):.2f} | "
                  f"{100 * r['scale_error']:+.1f} % | {np.mean(r['residual_px']):.2f} | "
                  f"{100 * r['pcp_true_calibration']:.1f} | {100 * r['pcp_estimated_calibration']:.1f} | "
                  f"{r['seconds']:.1f} |")
        print(f"| **{n}** | mean | **{100 * np.mean([r['mean_centre_error_m'] for r in rows]):.2f}** | | | | "
              f"**{100 * np.mean([r['pcp_true_calibration'] for r in rows]):.1f}** | "
              f"**{100 * np.mean([r['pcp_estimated_calibration'] for r in rows]):.1f}** | |")

    if args.focal_error:
        _focal_section(sample, args)
    print(f"\n## Synchronization from people (5 cameras, true offsets {(OFFSETS - OFFSETS[0]).tolist()})\n")
    print("| epipolar geometry | seed | found offsets | exact | ambiguous | PCP true offsets | PCP found | "
          "PCP unsynchronized | seconds |")
    print("|---|---|---|---|---|---|---|---|---|")
    for calibrated in (True, False):
        for seed in range(args.seeds):
            r = sync_check(sample, 5, OFFSETS, seed, calibrated)
            ambiguous = [n for n, a in zip(r["cameras"], r["ambiguous"]) if a]
            print(f"| {'calibration' if calibrated else 'people'} | {seed} | {r['found_offsets']} | "
                  f"{'yes' if r['found_offsets'] == r['true_offsets'] else 'no'} | {', '.join(ambiguous) or '–'} | "
                  f"{100 * r['pcp_true_offsets']:.1f} | {100 * r['pcp_found_offsets']:.1f} | "
                  f"{100 * r['pcp_unsynchronized']:.1f} | {r['seconds']:.1f} |")
    return 0


def _focal_section(sample, args) -> None:
    print(f"\n## Focal lengths given {100 * args.focal_error:g} % off (alternately up and down)\n")
    print("| cameras | seed | focal lengths refined | worst focal error after | mean centre error (cm) | "
          "PCP true calib. | PCP estimated | seconds |")
    print("|---|---|---|---|---|---|---|---|")
    for n in args.cameras:
        for seed in range(args.seeds):
            for refine in (False, True):
                r = calibration_check(sample, n, seed, focal_error=args.focal_error, refine_focal=refine)
                print(f"| {n} | {seed} | {'yes' if refine else 'no'} | "
                      f"{100 * max(abs(e) for e in r['focal_error_found']):.1f} % | "
                      f"{100 * r['mean_centre_error_m']:.2f} | {100 * r['pcp_true_calibration']:.1f} | "
                      f"{100 * r['pcp_estimated_calibration']:.1f} | {r['seconds']:.1f} |")


if __name__ == "__main__":
    sys.exit(main())
