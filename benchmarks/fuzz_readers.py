"""Fuzz every reader with hypothesis and print, per reader, the cases tried and their outcomes.

The cases are those of ``tests/io/test_fuzz_readers.py`` (valid files made by the project's
writers, then mutated). A case ends in a valid object or one ``InputError`` line; anything
else is a crash, listed at the end with the exception and written to ``--crashes`` for
replay. Exit status 1 if any crash was found.

    python benchmarks/fuzz_readers.py                 # 1,000 cases per reader (19 readers)
    python benchmarks/fuzz_readers.py --cases 200 --seed 3
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1] / "tests"
sys.path[:0] = [str(TESTS), str(TESTS / "io")]                  # helpers, test_fuzz_readers

from hypothesis import HealthCheck, Phase, given, seed, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn  # noqa: E402
from rich.table import Table  # noqa: E402
from test_fuzz_readers import READERS, Tally, cases, make_seeds, run_case  # noqa: E402


def fuzz(cases_per_reader: int, random_seed: int, readers: list[str]) -> tuple[Tally, dict]:
    seeds = make_seeds()
    tally = Tally()
    seconds = {}
    with tempfile.TemporaryDirectory() as tmp, Progress(
            TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
            console=Console(stderr=True), transient=True) as progress:
        for reader in readers:
            task = progress.add_task(reader, total=cases_per_reader)
            root = Path(tmp) / reader

            @seed(random_seed)
            @settings(max_examples=cases_per_reader, deadline=None, database=None, phases=[Phase.generate],
                      suppress_health_check=list(HealthCheck))
            @given(st.data())
            def one(data):  # runs within this iteration: the loop variables are the current ones
                run_case(reader, data.draw(cases(reader, seeds)), root, tally, strict=False)  # noqa: B023
                progress.advance(task)  # noqa: B023

            start = time.perf_counter()
            one()
            seconds[reader] = time.perf_counter() - start
    return tally, seconds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=1000, help="cases per reader (default 1000)")
    parser.add_argument("--seed", type=int, default=0, help="hypothesis seed (default 0)")
    parser.add_argument("--reader", action="append", choices=sorted(READERS), help="only these readers")
    parser.add_argument("--crashes", type=Path, default=Path("fuzz-crashes.json"),
                        help="where to write one example of each crash (only when there are crashes)")
    args = parser.parse_args()
    logging.disable(logging.WARNING)                  # readers warn about ignored images
    readers = args.reader or sorted(READERS)
    tally, seconds = fuzz(args.cases, args.seed, readers)

    table = Table(title=f"reader fuzzing (hypothesis, seed {args.seed})")
    for column in ("reader", "cases", "valid", "InputError", "uncaught", "seconds"):
        table.add_column(column, justify="left" if column == "reader" else "right")
    total = {"cases": 0, "valid": 0, "input_error": 0, "crash": 0}
    for reader in readers:
        c = tally.counts.get(reader, {})
        n = sum(c.values())
        row = {"cases": n, "valid": c.get("valid", 0), "input_error": c.get("input_error", 0),
               "crash": c.get("crash", 0)}
        for k in total:
            total[k] += row[k]
        table.add_row(reader, *(str(row[k]) for k in ("cases", "valid", "input_error", "crash")),
                      f"{seconds[reader]:.1f}")
    table.add_row("all", *(str(total[k]) for k in ("cases", "valid", "input_error", "crash")),
                  f"{sum(seconds.values()):.1f}")
    Console().print(table)
    if tally.crashes:
        print(f"{len(tally.crashes)} distinct uncaught exceptions:")
        for key, (message, _) in tally.crashes.items():
            print(f"  {key}: {message}")
        args.crashes.write_text(json.dumps({k: {p: d.decode("latin-1") for p, d in files.items()}
                                            for k, (_, files) in tally.crashes.items()}, indent=1))
        print(f"examples written to {args.crashes}")
        return 1
    print("no uncaught exception")
    return 0


if __name__ == "__main__":
    sys.exit(main())
