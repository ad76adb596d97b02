"""Throughput of ``mvm batch`` (clips per second) against the number of workers, and the wall
time of the whole Mannequin data set on a cluster estimated from the measured per-clip cost.

    python benchmarks/batch_throughput.py [--clips 16] [--people 4] [--frames 86] [--workers 1 2]
                                          [--ray] [--nodes 16] [--cores-per-node 32]

Clips are simulated scenes the size of the paper's (85.9 frames and about 4 people per clip:
2,172 3D poses in 550 clips), run through ``reconstruct`` and ``export``. Each measurement is a
fresh copy of the clips, so every stage really runs. The estimate scales the measured
core-seconds per clip to ``--sequences`` × ``--clips-per-sequence`` clips on ``--nodes`` ×
``--cores-per-node`` workers at the parallel efficiency measured here; ``--sfm-core-seconds``
adds the SfM stage's cost per clip (the figure of docs/results.md: 158 s on 2 cores for 100 frames) and
``--detect-core-seconds`` the network's detection on CPU (8 s per frame), which a simulated
clip does not have.
"""
from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

from mvm.batch import run_batch
from mvm.io.ground_truth import write_simulation
from mvm.sim.simulate import SimConfig, simulate


def make_clips(root: Path, clips: int, people: int, frames: int) -> None:
    for i in range(clips):
        scene, truth = simulate(SimConfig(people=people, frames=frames, seed=i))
        write_simulation(root / f"seq{i // 5:02d}" / f"clip{i:02d}", scene, truth)


def measure(template: Path, engine: str, workers: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "root"
        shutil.copytree(template, root)
        t = time.perf_counter()
        summary = run_batch(root, stages=("reconstruct", "export"), engine=engine, workers=workers)
        wall = time.perf_counter() - t
    assert summary.done == summary.clips and not summary.failed, summary.failed
    core_s = sum(summary.stage_seconds.values())
    return {"engine": engine, "workers": workers, "clips": summary.clips, "wall_s": wall,
            "clips_per_s": summary.clips / wall, "core_s_per_clip": core_s / summary.clips}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=16)
    parser.add_argument("--people", type=int, default=4)
    parser.add_argument("--frames", type=int, default=86)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--ray", action="store_true", help="Also measure the Ray engine (local instance).")
    parser.add_argument("--sequences", type=int, default=2000)
    parser.add_argument("--clips-per-sequence", type=float, default=5.5)
    parser.add_argument("--nodes", type=int, default=16)
    parser.add_argument("--cores-per-node", type=int, default=32)
    parser.add_argument("--sfm-core-seconds", type=float, default=158 * 2 * 86 / 100,
                        help="Core-seconds of SfM per clip (default: docs/results.md's 158 s × 2 cores, scaled to "
                             "86 frames).")
    parser.add_argument("--detect-core-seconds", type=float, default=8.0 * 86,
                        help="Core-seconds of the network's detection per clip on CPU (default: docs/results.md's "
                             "8 s per frame × 86 frames; on a GPU node it is a small fraction).")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        template = Path(tmp) / "clips"
        make_clips(template, args.clips, args.people, args.frames)
        rows = [measure(template, "local", w) for w in args.workers]
        if args.ray:
            rows += [measure(template, "ray", w) for w in args.workers]
    print(f"{args.clips} simulated clips, {args.people} people, {args.frames} frames each; stages reconstruct, "
          f"export; {os.cpu_count()} cores")
    print(f"{'engine':<7}{'workers':>8}{'wall s':>9}{'clips/s':>9}{'core-s/clip':>13}{'speed-up':>10}")
    base = {r["engine"]: r for r in rows if r["workers"] == min(args.workers)}
    for r in rows:
        speedup = r["clips_per_s"] / base[r["engine"]]["clips_per_s"]
        print(f"{r['engine']:<7}{r['workers']:>8}{r['wall_s']:>9.2f}{r['clips_per_s']:>9.3f}"
              f"{r['core_s_per_clip']:>13.3f}{speedup:>10.2f}")
    # Per clip: the worker's own seconds (the stages), and what the run adds around them
    # (pool start-up, scheduling, the manifest's transactions), from the run with most workers.
    local = [r for r in rows if r["engine"] == "local"]
    one = min(local, key=lambda r: r["workers"])
    many = max(local, key=lambda r: r["workers"])
    overhead = max(0.0, many["wall_s"] * many["workers"] / many["clips"] - one["core_s_per_clip"])
    n = int(args.sequences * args.clips_per_sequence)
    cores = args.nodes * args.cores_per_node
    print(f"per clip: {one['core_s_per_clip']:.3f} core-s in the stages (1 worker), "
          f"{overhead:.3f} core-s around them ({many['workers']} workers)")
    for label, cost in (("reconstruct + export", one["core_s_per_clip"] + overhead),
                        (f"+ SfM ({args.sfm_core_seconds:.0f} core-s per clip)",
                         one["core_s_per_clip"] + overhead + args.sfm_core_seconds),
                        (f"+ SfM + detection on CPU ({args.detect_core_seconds:.0f} core-s per clip)",
                         one["core_s_per_clip"] + overhead + args.sfm_core_seconds + args.detect_core_seconds)):
        seconds = n * cost / cores
        print(f"estimate, {label}: {n} clips × {cost:.2f} core-s / ({args.nodes} nodes × {args.cores_per_node} "
              f"cores) = {seconds:.0f} s ({seconds / 3600:.2f} h)")

if __name__ == "__main__":
    main()
