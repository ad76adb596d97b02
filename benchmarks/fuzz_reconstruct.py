"""Fuzz reconstruction with hypothesis: mutated simulated scenes in memory (``reconstruct``)
and on disk (``mvm reconstruct`` on damaged scene directories).

Prints the cases tried, how many gave a result and how many were refused with a one-line
``InputError``, and every uncaught exception (type, place, one failing case). The contract
(see ``tests/core/test_fuzz_reconstruct.py``): a valid result with finite-or-null numbers, or an
``InputError``; nothing else.

    python benchmarks/fuzz_reconstruct.py                  # 10,000 in memory + 300 on disk
    python benchmarks/fuzz_reconstruct.py --cases 2000 --disk-cases 50 --seed 1
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path

from hypothesis import HealthCheck, given, seed, settings

TESTS = Path(__file__).resolve().parents[1] / "tests"
sys.path[:0] = [str(TESTS), str(TESTS / "core")]                  # helpers, test_fuzz_reconstruct

from test_fuzz_reconstruct import base_scenes, cases, cli_cases, run_case, run_cli_case  # noqa: E402


def _where(error: BaseException) -> str:
    frames = traceback.extract_tb(error.__traceback__)
    inside = [f for f in frames if "/mvm/" in f.filename] or frames
    f = inside[-1]
    return f"{Path(f.filename).name}:{f.lineno} ({f.name})"


def fuzz(n: int, strategy, runner, random_seed: int, label: str) -> tuple[Counter, dict]:
    outcomes: Counter = Counter()
    crashes: dict = {}
    from rich.progress import Progress

    with Progress(transient=True) as progress:
        task = progress.add_task(label, total=n)

        @seed(random_seed)
        @settings(max_examples=n, deadline=None, database=None,
                  suppress_health_check=list(HealthCheck))
        @given(strategy)
        def one(case):
            try:
                outcomes[runner(case)] += 1
            except Exception as e:                       # noqa: BLE001 - this is what we count
                outcomes["crash"] += 1
                key = (type(e).__name__, _where(e))
                crashes.setdefault(key, (str(e)[:200], case))
            progress.advance(task)

        one()
    return outcomes, crashes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", type=int, default=10_000, help="in-memory cases")
    parser.add_argument("--disk-cases", type=int, default=300, help="on-disk (CLI) cases")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    logging.disable(logging.WARNING)                     # degenerate scenes warn by design
    base_scenes()

    t = time.perf_counter()
    memory, memory_crashes = fuzz(args.cases, cases, lambda c: run_case(*c), args.seed, "in memory")
    memory_s = time.perf_counter() - t

    with tempfile.TemporaryDirectory() as tmp:
        counter = iter(range(10**9))

        def disk_case(c):
            base, ops, file_op, s, refine = c
            return run_cli_case(Path(tmp) / f"s{next(counter)}" / "scene", base, ops, file_op, s, refine)

        t = time.perf_counter()
        disk, disk_crashes = fuzz(args.disk_cases, cli_cases, disk_case, args.seed, "on disk")
        disk_s = time.perf_counter() - t

    print(f"fuzz_reconstruct (hypothesis seed {args.seed})")
    for label, outcomes, crashes, seconds in (("in memory (reconstruct)", memory, memory_crashes, memory_s),
                                              ("on disk (mvm reconstruct)", disk, disk_crashes, disk_s)):
        total = sum(outcomes.values())
        print(f"  {label}: {total} cases in {seconds:.0f} s: {outcomes['result']} results, "
              f"{outcomes['refused']} refused with an InputError, {outcomes['crash']} uncaught exceptions")
        for (kind, where), (message, case) in crashes.items():
            print(f"    CRASH {kind} at {where}: {message}\n      case: {case!r}")
    total_crashes = memory["crash"] + disk["crash"]
    print(f"  total: {sum(memory.values()) + sum(disk.values())} cases, {total_crashes} uncaught exceptions")
    sys.exit(1 if total_crashes else 0)


if __name__ == "__main__":
    main()
