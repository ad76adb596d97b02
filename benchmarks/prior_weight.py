"""Does one rule give every geometry its best prior weight? The refinement's prior weight
(``Config.prior_weight`` times :func:`mvm.core.refine_units.spread_factor` of each person's
view spread) scaled by a multiplier, on every geometry the project benchmarks:

    python benchmarks/prior_weight.py [--quick] [--multipliers 0.25,0.5,1,2,4]
        [--cases demo,arcs,dome31,dome18,crowd,rig] [--seeds 2] [--crowd-seeds 2] [--arcs 30,60,90]
        [--no-oracle]

- ``demo``: ``mvm demo --seed 0`` (six people, a 60° hand-held tour; :mod:`mvm.eval.demo`).
- ``dome31``, ``dome18``: the CMU Panoptic dome, 31 cameras with the default detector and 18
  with heavy detector errors, each instant on its own (``benchmarks/thresholds.py``).
- ``arcs``: the demo's scene (seeds 0, 1, ... as many as ``--seeds``) on tours of 30° to 180°
  (``--arcs``: the views' spread from a narrow arc to all round).
- ``crowd``: frozen crowds of 8-15 people, one hand-held 1080p camera (``benchmarks/thresholds.py``).
- ``rig``: the rig driver's instants, 5 cameras, the crowd benchmark's detector
  (``benchmarks/rig_panoptic.py``'s second table): refined per instant ("before") and refined
  along tracks with their bone lengths ("after").

Each row: MPJPE (mm, over the persons found) for each multiplier, ``*`` the best, the default
(multiplier 1) in brackets; the median view spread and spread factor of the persons refined; the
oracle (true grouping, exhaustive RANSAC, no refinement) where the case has one. The multipliers
of one row share the same detector draws. ``--quick``: one draw and one crowd scene.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import rig_panoptic  # noqa: E402  (the benchmarks' own scenes)
import thresholds  # noqa: E402

import mvm.core.refine_units as units  # noqa: E402
from mvm.core.config import Config  # noqa: E402
from mvm.core.reconstruct import reconstruct  # noqa: E402
from mvm.eval.demo import evaluate  # noqa: E402
from mvm.eval.panoptic import load_sample  # noqa: E402
from mvm.sim.detector import DetectorErrors  # noqa: E402
from mvm.sim.simulate import SimConfig, simulate  # noqa: E402

MULTIPLIERS = (0.25, 0.5, 1.0, 2.0, 4.0)
#: The tours of the ``arcs`` case (deg): from narrower than the demo's to all round.
ARCS = (30.0, 60.0, 90.0, 120.0, 180.0)
CASES = ("demo", "arcs", "dome31", "dome18", "crowd", "rig")


class SpreadLog:
    """Records the view spreads :func:`mvm.core.refine_units.prior_weights` is given (every
    caller: scenes, rig instants, tracks) while active."""

    def __init__(self):
        self.spreads: list[np.ndarray] = []
        self._original = units.view_spread

    def __enter__(self):
        def recording(points, centers, used):
            spread = self._original(points, centers, used)
            self.spreads.append(spread)
            return spread
        units.view_spread = recording
        return self

    def __exit__(self, *exc):
        units.view_spread = self._original

    def medians(self) -> tuple[float, float]:
        """The median spread and spread factor of the persons recorded (NaN spreads left out)."""
        s = np.concatenate(self.spreads) if self.spreads else np.zeros(0)
        s = s[np.isfinite(s)]
        if not len(s):
            return float("nan"), float("nan")
        return float(np.median(s)), float(np.median(units.spread_factor(s)))


def scaled(multipliers) -> list[tuple[str, Config]]:
    base = Config()
    return [(f"{m:g}", base.replace(prior_weight=base.prior_weight * m)) for m in multipliers]


def demo_case(configs, arc_deg: float = 60.0, seeds: int = 1) -> dict:
    """The demo's scene (seeds 0, 1, ...) on a tour of ``arc_deg``: MPJPE, the mean over the seeds."""
    out = {name: [] for name, _ in configs}
    for seed in range(seeds):
        scene, truth = simulate(SimConfig(seed=seed, arc_deg=arc_deg))
        for name, config in configs:
            out[name].append(evaluate(reconstruct(scene, config), truth)["mpjpe_mm"])
    return {name: float(np.mean(v)) for name, v in out.items()}


def rig_dome_case(sample, n: int, errors: DetectorErrors, seeds: int, configs, oracle: bool) -> dict:
    extra = [("oracle", Config())] if oracle else []
    r = thresholds.rig_case(sample, n, errors, seeds, configs + extra)
    return {name: v["mpjpe_mm"] for name, v in r.items()}


def crowd_case(seeds: int, configs, oracle: bool) -> dict:
    extra = [("oracle", Config())] if oracle else []
    return {name: v["mpjpe_mm"] for name, v in thresholds.crowd_case(seeds, configs + extra).items()}


def rig_tracks_case(sample, seeds: int, configs) -> tuple[dict, dict]:
    """Per-instant refinement ("before") and along tracks ("after"): two rows."""
    rows = {name: rig_panoptic.temporal_table(sample, seeds, config) for name, config in configs}
    return ({name: r["before"]["mpjpe_mm"] for name, r in rows.items()},
            {name: r["after"]["mpjpe_mm"] for name, r in rows.items()})


def measured(run) -> tuple[dict | tuple, tuple[float, float]]:
    """``run()`` with the view spreads it refines with recorded: its result, the medians."""
    with SpreadLog() as log:
        result = run()
    return result, log.medians()


def row(case: str, mpjpe: dict, spread: tuple[float, float], names: list[str]) -> str:
    values = [mpjpe[n] for n in names]
    best = names[int(np.nanargmin(values))]
    cells = []
    for n in names:
        text = f"{mpjpe[n]:.2f}" + ("*" if n == best else "")
        cells.append(f"[{text}]" if n == "1" else text)
    gain = mpjpe["1"] - mpjpe[best] if "1" in mpjpe else float("nan")
    oracle = f"{mpjpe['oracle']:.2f}" if "oracle" in mpjpe else "-"
    return (f"| {case} | {spread[0]:.3f} | {spread[1]:.2f} | " + " | ".join(cells)
            + f" | {best} | {gain:.2f} | {oracle} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one detector draw, one crowd scene")
    parser.add_argument("--multipliers", default=",".join(f"{m:g}" for m in MULTIPLIERS))
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--seeds", type=int, default=2, help="detector draws per dome and rig case, scenes per arc")
    parser.add_argument("--crowd-seeds", type=int, default=2, help="crowd scenes")
    parser.add_argument("--no-oracle", action="store_true", help="leave the oracle out (the crowd's is slow)")
    parser.add_argument("--arcs", default=",".join(f"{a:g}" for a in ARCS), help="the arcs case's tours (deg)")
    parser.add_argument("--sequence", type=Path, default=thresholds.SEQUENCE)
    args = parser.parse_args()
    logging.disable(logging.WARNING)                  # the scenes' warnings: not what is measured here
    seeds, crowd_seeds = (1, 1) if args.quick else (args.seeds, args.crowd_seeds)
    configs = scaled(float(m) for m in args.multipliers.split(","))
    names = [name for name, _ in configs]
    cases, oracle = args.cases.split(","), not args.no_oracle
    if set(cases) - set(CASES):
        parser.error(f"--cases: {','.join(sorted(set(cases) - set(CASES)))}: not one of {','.join(CASES)}")
    if {"dome31", "dome18", "rig"} & set(cases) and not args.sequence.is_dir():
        print(f"Panoptic sample absent: {args.sequence}", file=sys.stderr)
        return 2
    sample = load_sample(args.sequence) if {"dome31", "dome18", "rig"} & set(cases) else None
    print(f"prior_weight {Config().prior_weight:g} times the spread factor, times each multiplier; "
          f"{seeds} draw(s) per dome and rig case, {crowd_seeds} crowd scene(s); MPJPE mm, "
          "[default], * best")
    print("| geometry | median spread | median spread factor | " + " | ".join(f"x{n}" for n in names)
          + " | best | default − best mm | oracle |")
    print("|---|---|---|" + "---|" * len(names) + "---|---|---|")
    runs = {
        "demo": [("demo (60° tour, 6 people)", lambda: demo_case(configs))],
        "dome31": [("31-camera dome", lambda: rig_dome_case(sample, 31, DetectorErrors(), seeds, configs, oracle))],
        "dome18": [("18-camera dome, heavy noise",
                    lambda: rig_dome_case(sample, 18, thresholds.HEAVY, seeds, configs, oracle))],
        "arcs": [(f"demo scene, {a:g}° tour ({seeds} scenes)", lambda a=a: demo_case(configs, a, seeds))
                 for a in (float(a) for a in args.arcs.split(","))],
        "crowd": [(f"hand-held crowd ({crowd_seeds} scenes)", lambda: crowd_case(crowd_seeds, configs, oracle))],
    }
    for case in cases:
        if case == "rig":
            (before, after), spread = measured(lambda: rig_tracks_case(sample, seeds, configs))
            print(row("rig instants, 5 cameras, per instant", before, spread, names), flush=True)
            print(row("rig instants, 5 cameras, tracks", after, spread, names), flush=True)
            continue
        for label, run in runs[case]:
            mpjpe, spread = measured(run)
            print(row(label, mpjpe, spread, names), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
