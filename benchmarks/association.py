"""The paper's grouping against the association consistent in 3D, beside the true grouping.

    python benchmarks/association.py                     # hard preset, 10 people, 250 frames, 90° arc
    python benchmarks/association.py --sweep             # crowd size 5-15 x arc 20-120°
    python benchmarks/association.py --seeds 0 1 2 --people 10 --frames 250 --arc 90

Geometry only (``use_appearance=False``). Per scene and method: pairwise precision and recall of
the groups, persons found / estimated / true, MPJPE (mm) and the reconstruction's time (s).
The oracle reconstructs the same scene from the true grouping (``person`` of the ground truth)
with plain RANSAC triangulation and no refinement; "3d (tri)" is the new association without
refinement, to compare triangulations like for like; "3d+order" adds the order of the video.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from mvm.core.config import Config
from mvm.core.reconstruct import reconstruct
from mvm.eval.demo import evaluate
from mvm.sim.simulate import SimConfig, simulate


def true_groups(truth) -> list[np.ndarray]:
    """The true grouping: the 2D poses of each simulated person (false positives left out)."""
    return [np.flatnonzero(truth.person == g) for g in range(len(truth.poses3d))]


def crowd_scene(people: int, frames: int, arc: float, seed: int, preset: str = "hard") -> SimConfig:
    """A frozen crowd: the ``preset`` detector, standing and seated people mixed, close pairs."""
    return SimConfig.preset(preset, people=people, frames=frames, arc_deg=arc, seed=seed,
                            close_pairs=max(2, people // 4), postures=(0.5, 0.4, 0.1))


def run_scene(sim: SimConfig, config: Config, only: list[str] | None = None) -> dict[str, dict]:
    """Every method on one simulated scene: ``{method: evaluate(...) + time_s}``."""
    scene, truth = simulate(sim)
    rows = {}
    methods = {
        "paper": (config.replace(association="paper"), None),
        "3d": (config.replace(video_order=False), None),
        "3d+order": (config.replace(video_order=True), None),
        "3d (tri)": (config.replace(refine=False, video_order=False), None),
        "oracle": (config.replace(refine=False), true_groups(truth)),
    }
    for name, (cfg, groups) in methods.items():
        if only and name not in only:
            continue
        t = time.perf_counter()
        result = reconstruct(scene, cfg, groups=groups)
        elapsed = time.perf_counter() - t
        rows[name] = {**evaluate(result, truth), "time_s": elapsed}
    return rows


def print_rows(label: str, rows: dict[str, dict]) -> None:
    for name, r in rows.items():
        print(f"{label:<28} {name:<9} P {r['precision']:.4f}  R {r['recall']:.4f}  persons "
              f"{r['persons_found']:>2}/{r['persons_estimated']:>2}/{r['persons_true']:>2}  "
              f"MPJPE {r['mpjpe_mm']:6.1f} mm  E_R {r['E_R_px']:5.2f} px  {r['time_s']:.2f} s", flush=True)


def summarize(all_rows: list[dict[str, dict]]) -> None:
    print("\nmean over scenes (persons: found/estimated/true summed)")
    for name in all_rows[0]:
        rs = [rows[name] for rows in all_rows]
        exact = sum(r["persons_found"] == r["persons_true"] == r["persons_estimated"] for r in rs)
        print(f"  {name:<9} P {np.mean([r['precision'] for r in rs]):.4f}  R {np.mean([r['recall'] for r in rs]):.4f}  "
              f"min P {min(r['precision'] for r in rs):.4f}  min R {min(r['recall'] for r in rs):.4f}  persons "
              f"{sum(r['persons_found'] for r in rs)}/{sum(r['persons_estimated'] for r in rs)}/"
              f"{sum(r['persons_true'] for r in rs)}  exact count {exact}/{len(rs)}  "
              f"MPJPE {np.mean([r['mpjpe_mm'] for r in rs]):.1f} mm  time {np.mean([r['time_s'] for r in rs]):.2f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--people", type=int, default=10)
    parser.add_argument("--frames", type=int, default=250)
    parser.add_argument("--arc", type=float, default=90.0)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--preset", default="hard")
    parser.add_argument("--sweep", action="store_true", help="crowd size 5-15 x arc 20-120°, 120 frames")
    parser.add_argument("--only", nargs="*", help="methods to run (default all)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="Config overrides")
    args = parser.parse_args()
    from mvm.settings.tables import load_config

    config = load_config(None, dict(kv.split("=", 1) for kv in args.set)).replace(use_appearance=False)
    import logging

    logging.disable(logging.WARNING)                 # the per-scene warnings; figures only
    all_rows = []
    if args.sweep:
        for people in (5, 10, 15):
            for arc in (20, 45, 90, 120):
                for seed in args.seeds:
                    rows = run_scene(crowd_scene(people, 120, arc, seed, args.preset), config, args.only)
                    print_rows(f"{people} people {arc}° seed {seed}", rows)
                    all_rows.append(rows)
    else:
        for seed in args.seeds:
            rows = run_scene(crowd_scene(args.people, args.frames, args.arc, seed, args.preset), config, args.only)
            print_rows(f"{args.people}p {args.frames}f {args.arc:g}° seed {seed}", rows)
            all_rows.append(rows)
    summarize(all_rows)


if __name__ == "__main__":
    main()
