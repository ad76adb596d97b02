"""Time each stage of the reconstruction of a 250-frame, 10-person simulated scene.

    python benchmarks/reconstruct_timing.py [--frames 250] [--people 10] [--repeats 3]

Prints the best of ``--repeats`` runs per stage (seconds) and the accuracy against the truth.
Targets on a 2-core machine: matching < 0.5 s, whole reconstruction < 3 s.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from mvm.core.config import Config
from mvm.core.reconstruct import reconstruct
from mvm.eval.demo import evaluate
from mvm.sim.simulate import SimConfig, simulate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=250)
    parser.add_argument("--people", type=int, default=10)
    parser.add_argument("--arc", type=float, default=90.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    sim = SimConfig(people=args.people, frames=args.frames, arc_deg=args.arc, seed=args.seed)
    scene, truth = simulate(sim)
    print(f"scene: {args.people} people, {args.frames} frames, {len(scene.poses)} 2D poses")
    config = Config()
    best: dict[str, float] = {}
    for _ in range(args.repeats):
        t = time.perf_counter()
        result = reconstruct(scene, config)
        wall = time.perf_counter() - t
        for key, value in {**result.timings, "wall_s": wall}.items():
            best[key] = min(best.get(key, np.inf), value)
    for key in ("matching_s", "triangulation_s", "refinement_s", "total_s", "wall_s"):
        print(f"{key:>16}: {best[key]:.3f}")
    report = evaluate(result, truth)
    print(f"persons found {report['persons_found']}/{report['persons_true']}, "
          f"precision {report['precision']:.4f}, recall {report['recall']:.4f}, "
          f"MPJPE {report['mpjpe_mm']:.1f} mm, PA-MPJPE {report['pa_mpjpe_mm']:.1f} mm, "
          f"E_R {report['E_R_px']:.2f} px")


if __name__ == "__main__":
    main()
