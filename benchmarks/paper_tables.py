"""Reproduce the layout of the paper's Tables 1 and 2 on simulated clips with ground truth,
sweep the difficulty, and plot the matching time of every method against the 2D poses.

    python benchmarks/paper_tables.py [--quick] [--out benchmarks/results] [--refine]

Writes ``paper_tables.md`` (every table), ``clips.csv`` (one row per clip and method),
``sweeps.csv`` and ``matching_time.png`` (log-log) to ``--out``.
"""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from mvm.core.config import Config
from mvm.eval.bench import run_bench
from mvm.eval.bench_files import write_bench_report

SHARED_TRAJECTORIES = Path(__file__).resolve().parents[2] / "shared" / "data" / "camera_trajectories"


def main(quick: bool, out: Path, refine: bool) -> Path:
    trajectories = sorted(str(p) for p in SHARED_TRAJECTORIES.glob("*.txt")) if SHARED_TRAJECTORIES.is_dir() else []
    t = time.perf_counter()
    result = run_bench(quick=quick, config=Config(refine=refine), trajectories=trajectories,
                       progress=lambda message: logging.info(message))
    command = "python benchmarks/paper_tables.py" + (" --quick" if quick else "") + (" --refine" if refine else "")
    return write_bench_report(result, out, command, time.perf_counter() - t)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="two tiny clips, short sweeps (CI)")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    parser.add_argument("--refine", action="store_true", help="run the pose-prior refinement too")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")
    main(args.quick, args.out, args.refine)
    print((args.out / "paper_tables.md").read_text())
