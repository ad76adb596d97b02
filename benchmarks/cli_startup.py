"""Whole-process start-up time of the ``mvm`` command (best of N runs), and what it imports.

    python benchmarks/cli_startup.py [--runs 15]

Each command runs as a fresh ``python -m mvm ...`` process, timed from spawn to exit, so the
figures include the interpreter's own start-up (shown as the baseline ``python -c pass``). The
best of N is the figure to compare: on a loaded machine the other runs measure the load; the
CPU seconds (user + system, best of N) are less sensitive to it.
Target: ``mvm --version`` and ``mvm --help`` under 0.25 s.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

COMMANDS = {
    "python -c pass (baseline)": [sys.executable, "-c", "pass"],
    "mvm --version": [sys.executable, "-m", "mvm", "--version"],
    "mvm --help": [sys.executable, "-m", "mvm", "--help"],
    "mvm reconstruct --help": [sys.executable, "-m", "mvm", "reconstruct", "--help"],
    "mvm rig reconstruct --help": [sys.executable, "-m", "mvm", "rig", "reconstruct", "--help"],
    "import mvm.rig.reconstruct_rig": [sys.executable, "-c", "import mvm.rig.reconstruct_rig"],
}
HEAVY = ("numpy", "scipy", "torch", "cv2", "pycolmap", "rich", "onnxruntime", "mvm.core.reconstruct")

#: Runs ``mvm --help`` in-process and prints the heavy modules it imported (JSON).
_PROBE = f"""
import json, sys
from mvm.cli import main
try:
    main(["--help"], standalone_mode=False)
finally:
    print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in {HEAVY!r} or m in {HEAVY!r})))
"""


def best_time(command: list[str], runs: int) -> tuple[float, float, float]:
    """(best, median) wall seconds and best CPU seconds (user + system, which a loaded machine
    inflates less) of ``runs`` executions of ``command``."""
    times, cpu = [], []
    for _ in range(runs):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
        times.append(time.perf_counter() - t)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    times.sort()
    return times[0], times[len(times) // 2], min(cpu)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15)
    args = parser.parse_args()
    print(f"{'command':28s} {'best s':>8s} {'median s':>9s} {'CPU s':>7s}   (whole process, {args.runs} runs)")
    for label, command in COMMANDS.items():
        best, median, cpu = best_time(command, args.runs)
        print(f"{label:28s} {best:8.3f} {median:9.3f} {cpu:7.3f}")
    probe = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, check=True)
    heavy = json.loads(probe.stdout.strip().splitlines()[-1])
    print(f"heavy modules imported by `mvm --help`: {', '.join(heavy) or 'none'}")


if __name__ == "__main__":
    main()
