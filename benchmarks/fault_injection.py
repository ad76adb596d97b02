"""SIGKILL fault injection on ``mvm reconstruct``: kill runs at random moments and at chosen
points of writing ``poses3d.json`` and then its record ``poses3d.inputs.json`` (before the
rename, half-way through the write, after the rename: :data:`test_faults.FAULTS`), on fresh
scenes and on scenes with a previous output; then rerun.

Prints faults injected, outcomes after the kill (absent / complete / partial), outputs lost (a
previous complete output gone or damaged: must be 0), partial outputs (must be 0), reruns
that failed, and stale temporary files left after the rerun.

Then output locations: ``export``, ``overlay`` and ``rig reconstruct`` pointed at random
locations of :data:`test_faults.LOCATIONS` (the inputs, a folder holding them, a link, a user's
folder, beside a user's ``.NAME.*`` folders, ...) under random names; prints how many were
refused and written as they should be, and the violations (must be 0).

    python benchmarks/fault_injection.py                       # 60 random + 10 per write point + 60 locations
    python benchmarks/fault_injection.py --random 200 --per-point 30 --locations 300
"""
from __future__ import annotations

import argparse
import signal
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

TESTS = Path(__file__).resolve().parents[1] / "tests"
sys.path[:0] = [str(TESTS), str(TESTS / "io")]                  # helpers, test_faults

from test_faults import (  # noqa: E402
    FAULTS,
    FOLDER_COMMANDS,
    LOCATIONS,
    check_location,
    copy_scene,
    output_of,
    persons_of,
    stale_temporaries,
    start,
    state,
    write_location_inputs,
    write_test_scene,
)

#: Pieces of the output names the location cases draw.
NAME_PARTS = ("out", "mvm", "overlay", "ds", "my results", "ünï", ".hidden", "a.b", "x-1", "frames")


def location_cases(n: int, rng) -> Counter:
    """``n`` random (command, location, name) cases of :func:`test_faults.check_location`."""
    counts: Counter = Counter()
    kinds = list(LOCATIONS)
    with tempfile.TemporaryDirectory() as tmp:
        inputs = write_location_inputs(Path(tmp) / "inputs")
        for i in range(n):
            command = FOLDER_COMMANDS[rng.integers(len(FOLDER_COMMANDS))]
            kind = kinds[rng.integers(len(kinds))]
            name = "".join(NAME_PARTS[k] for k in rng.integers(len(NAME_PARTS), size=rng.integers(1, 3)))
            work = Path(tmp) / f"case{i}"
            work.mkdir()
            try:
                outcome = check_location(kind, command, inputs, work, name)
                counts[f"{outcome} as it should be"] += 1
            except AssertionError as e:
                counts["violations"] += 1
                print(f"location case {i}: {command} into {kind} ({name!r}): {e}")
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--random", type=int, default=60, help="kills at random delays")
    parser.add_argument("--per-point", type=int, default=10, help="kills at each write point")
    parser.add_argument("--locations", type=int, default=60, help="random output-location cases")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    counts: Counter = Counter()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scene0 = write_test_scene(tmp / "ref" / "scene", people=4, frames=60)
        t = time.perf_counter()
        assert start(scene0).wait(300) == 0
        run_s = time.perf_counter() - t
        reference = persons_of(output_of(scene0))
        plan = [("random", None)] * args.random + [(p, None) for p in FAULTS for _ in range(args.per_point)]
        for i, (kind, _) in enumerate(plan):
            with_output = bool(rng.integers(2))
            scene = copy_scene(scene0, tmp / f"s{i}", with_output)
            if kind == "random":
                process = start(scene)
                time.sleep(rng.uniform(0.0, 1.2 * run_s))
                process.send_signal(signal.SIGKILL)
                code = process.wait(300)
            else:
                code = start(scene, kind).wait(300)
            killed = code == -signal.SIGKILL
            counts["faults injected"] += killed
            counts["runs finished before the kill"] += not killed
            outcome = state(scene, reference)
            counts[f"after kill: {outcome}"] += 1
            counts["outputs lost"] += with_output and outcome != "complete"
            counts["partial outputs"] += outcome == "partial"
            counts["stale temporaries after kill"] += bool(stale_temporaries(scene))
            rerun = start(scene)
            code = rerun.wait(300)
            if code != 0 or state(scene, reference) != "complete":
                counts["reruns failed"] += 1
                print(f"rerun failed after {kind} kill (exit {code}, output {state(scene, reference)}): "
                      f"{rerun.stderr.read().decode()[-400:]}")
            counts["stale temporaries after rerun"] += bool(stale_temporaries(scene))
    print(f"fault_injection: {len(plan)} runs of mvm reconstruct (one undisturbed run: {run_s:.2f} s), "
          f"{time.perf_counter() - t0:.0f} s in all")
    for key in ("faults injected", "runs finished before the kill", "after kill: absent", "after kill: complete",
                "after kill: partial", "stale temporaries after kill", "outputs lost", "partial outputs",
                "reruns failed", "stale temporaries after rerun"):
        print(f"  {key}: {counts[key]}")
    t0 = time.perf_counter()
    locations = location_cases(args.locations, rng)
    print(f"output locations: {args.locations} cases of export, overlay and rig reconstruct, "
          f"{time.perf_counter() - t0:.0f} s")
    for key in ("refused as it should be", "written as it should be", "violations"):
        print(f"  {key}: {locations[key]}")
    failed = counts["outputs lost"] or counts["partial outputs"] or counts["reruns failed"] or locations["violations"]
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
