"""The rig evaluation table on the real CMU Panoptic sample (README, "Synchronized rigs").

    python benchmarks/rig_panoptic.py [--seeds 3] [--refine]

Real 31-camera HD calibration (with lens distortion) and real 3D poses of three people over
20 instants; 2D detections simulated from them (noise 1 % of the person's image height,
occlusion, 3 % dropped joints, 1 % left/right swaps, 2 % outlier joints, 0.1 false
detections per view), distorted, then undistorted by the pipeline. Cameras spread around the dome.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mvm.core.config import Config
from mvm.eval.panoptic import evaluate, load_sample

SEQUENCE = Path(__file__).resolve().parents[2] / "shared" / "data" / "panoptic" / "160906_band1"


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--refine", action="store_true")
    parser.add_argument("--sequence", type=Path, default=SEQUENCE)
    args = parser.parse_args()
    if not args.sequence.is_dir():
        print(f"Panoptic sample absent: {args.sequence}", file=sys.stderr)
        return 2
    sample = load_sample(args.sequence)
    config = Config(refine=args.refine)
    print("| cameras | MPJPE mm | PA-MPJPE mm | PCP | persons found | AP@25 | AP@50 | AP@150 | instants/s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in (5, 10, 31):
        r = evaluate(sample, n, config, seeds=args.seeds)
        print(f"| {n} | {r['mpjpe_mm']:.1f} | {r['pa_mpjpe_mm']:.1f} | {r['pcp']:.3f} | {r['found']:.3f} | "
              f"{r['AP@25']:.3f} | {r['AP@50']:.3f} | {r['AP@150']:.3f} | {r['instants_per_s']:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
