"""Completion through long occlusions on a simulated rig (docs/results.md, "Synchronized camera rigs").

    python benchmarks/rig_occlusion.py [--seeds 4] [--frames 150] [--joints wrist|arm]

A simulated 5-camera ring rig (:mod:`mvm.sim.rig_scene`: people playing real motions, the
default detector errors, no lens distortion). Every person loses one arm's wrist (``--joints
arm``: its elbow and wrist) for a stretch of 10 to 40 instants: that joint's keypoints are
dropped in all the views but 0 or 1 of them (drawn per stretch), as a body or a table hides a
limb from most of a rig. The rig's time steps run as ``mvm rig reconstruct`` runs them
(:func:`mvm.rig.reconstruct_rig.track_and_complete`).

Printed: the MPJPE of the hidden joints, split by how they came out (observed, interpolated,
inferred, missing), against the error of the observed joints around them (their elbows and
shoulders over the same stretch) and of all observed joints.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from mvm.core.completion import FLAG_NAMES, OBSERVED
from mvm.core.config import Config
from mvm.core.keypoints import INDEX
from mvm.metrics.poses import match_persons
from mvm.rig.instants import reconstruct_instants, rig_poses
from mvm.rig.options import RigOptions
from mvm.rig.reconstruct_rig import completion_prior, instants_config, rig_config, track_and_complete
from mvm.sim.rig_scene import RigSimConfig, simulate_rig

#: A person is the true person of smallest MPJPE within this distance. [m]
MATCH_M = 0.5
SIDES = ("left", "right")


def occlude(sim, rng: np.random.Generator, joints: str, lengths=(10, 40), wrong: bool = False) -> np.ndarray:
    """Hide one arm of every person of ``sim`` (in place, in ``sim.keypoints``) for a stretch of
    ``lengths`` instants, in all the views but 0 or 1 of them. ``wrong``: the views that do not
    see it report it anyway, each at the projection of a point 20 to 40 cm from the truth (a
    direction drawn per view and stretch), as a detector confuses a hidden hand with something
    near it.

    Returns ``hidden: (S, G, 17)`` bool, the (instant, person, joint) cells hidden from all views
    but at most one, and ``left: (G,)`` the views left seeing each person's hidden joints (0 or 1)."""
    S, G = sim.poses3d.shape[:2]
    V = len(sim.calibration.cameras.names)
    hidden = np.zeros((S, G, 17), bool)
    left = np.zeros(G, int)
    for g in range(G):
        side = SIDES[rng.integers(2)]
        js = [INDEX[f"{side}_wrist"]] + ([INDEX[f"{side}_elbow"]] if joints == "arm" else [])
        n = int(rng.integers(lengths[0], lengths[1] + 1))
        t0 = int(rng.integers(10, S - n - 10))
        left[g] = int(rng.integers(2))
        keep = rng.permutation(V)[:left[g]]                         # the 0 or 1 view still seeing it
        rows = (sim.person == g) & (sim.frame >= t0) & (sim.frame < t0 + n) & ~np.isin(sim.camera, keep)
        for j in js:
            hidden[t0:t0 + n, g, j] = True
            if not wrong:
                sim.keypoints[rows, j] = 0.0
                continue
            cameras = sim.calibration.cameras
            for v in np.setdiff1d(np.arange(V), keep):
                offset = rng.normal(size=3)
                offset *= rng.uniform(0.2, 0.4) / np.linalg.norm(offset)
                sel = np.flatnonzero(rows & (sim.camera == v))
                point = sim.poses3d[sim.frame[sel], g, j] + offset                  # (k, 3)
                uvw = np.einsum("ij,kj->ki", cameras.P[v], np.concatenate([point, np.ones((len(sel), 1))], 1))
                sim.keypoints[sel, j, :2] = uvw[:, :2] / uvw[:, 2:]
                sim.keypoints[sel, j, 2] = np.maximum(sim.keypoints[sel, j, 2], 0.5)
    return hidden, left


def run(seed: int, frames: int, joints: str, config: Config, prior, options: RigOptions, wrong: bool = False) -> dict:
    sim = simulate_rig(RigSimConfig(cameras=5, people=3, frames=frames, distortion=0.0, seed=seed))
    hidden, left = occlude(sim, np.random.default_rng(1000 + seed), joints, wrong=wrong)
    det = rig_poses(sim.keypoints, sim.frame, sim.camera, sim.score)
    cameras = sim.calibration.cameras
    persons = reconstruct_instants(cameras, det, instants_config(config), prior)
    _, persons, X, flags = track_and_complete(persons, options, prior, config, det, cameras)
    out = {"hidden": {f: [] for f in range(len(FLAG_NAMES))}, "around": [], "observed": [], "hidden_cells": 0,
           "confidence": [], "by_views": {0: [], 1: []}}
    around = np.zeros_like(hidden)
    for side in SIDES:                                     # the elbow and shoulder of a hidden wrist
        w, e, s = INDEX[f"{side}_wrist"], INDEX[f"{side}_elbow"], INDEX[f"{side}_shoulder"]
        around[..., e] |= hidden[..., w] & ~hidden[..., e]
        around[..., s] |= hidden[..., w]
    out["hidden_cells"] = int(hidden.sum())
    for t in range(frames):
        rows = np.flatnonzero(persons.instant == t)
        for p, g in match_persons(X[rows], sim.poses3d[t], MATCH_M):
            d = np.linalg.norm(X[rows[p]] - sim.poses3d[t, g], axis=-1)
            f = np.asarray(flags[rows[p]])
            for j in np.flatnonzero(hidden[t, g]):
                out["hidden"][int(f[j])].append(d[j])
                if f[j] != OBSERVED:
                    out["confidence"].append((d[j], float(persons.scores[rows[p], j])))
                    out["by_views"][int(left[g])].append(d[j])
            out["around"] += d[around[t, g] & (f == OBSERVED)].tolist()
            out["observed"] += d[~hidden[t, g] & (f == OBSERVED)].tolist()
    return out


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--joints", choices=("wrist", "arm"), default="wrist")
    parser.add_argument("--wrong", action="store_true", help="The views that do not see the joint report it "
                        "20-40 cm off instead of not at all.")
    parser.add_argument("--no-fill", action="store_true", help="Without the occlusion fill (occlusion_max_gap = 0).")
    args = parser.parse_args()
    config = rig_config()
    prior = completion_prior(config)
    options = RigOptions(frame_rate=30.0, occlusion_max_gap=0 if args.no_fill else RigOptions().occlusion_max_gap)
    total = {"hidden": {f: [] for f in range(len(FLAG_NAMES))}, "around": [], "observed": [], "hidden_cells": 0,
             "confidence": [], "by_views": {0: [], 1: []}}
    for seed in range(args.seeds):
        r = run(seed, args.frames, args.joints, config, prior, options, args.wrong)
        for f, v in r["hidden"].items():
            total["hidden"][f] += v
        for k in ("around", "observed", "confidence"):
            total[k] += r[k]
        total["hidden_cells"] += r["hidden_cells"]
        for k in (0, 1):
            total["by_views"][k] += r["by_views"][k]

    def mm(v):
        return f"{1000 * np.mean(v):.1f} ({len(v)})" if v else "- (0)"

    print(f"5 cameras, 3 people, {args.frames} instants, {args.seeds} seeds, hidden: {args.joints}"
          f"{' (reported off)' if args.wrong else ''}, "
          f"{'without' if args.no_fill else 'with'} the occlusion fill, "
          f"{total['hidden_cells']} hidden joint-instants")
    print("| hidden joints: " + " | ".join(FLAG_NAMES) + " | observed joints around them | all observed |")
    print("|---" * (len(FLAG_NAMES) + 2) + "|")
    print("| MPJPE mm (count) | " + " | ".join(mm(total["hidden"][f]) for f in range(len(FLAG_NAMES)))
          + f" | {mm(total['around'])} | {mm(total['observed'])} |")
    filled = [d for f in (2, 3) for d in total["hidden"][f]]
    if filled:
        print(f"filled hidden joints: MPJPE {1000 * np.mean(filled):.1f} mm, median {1000 * np.median(filled):.1f} mm, "
              f"90th percentile {1000 * np.percentile(filled, 90):.1f} mm")
    print("filled hidden joints seen by 0 views: MPJPE " + mm(total["by_views"][0]) + " mm; by 1 view: "
          + mm(total["by_views"][1]) + " mm")
    if total["confidence"]:
        d, c = np.array(total["confidence"]).T
        print(f"confidence of the filled joints: mean {c.mean():.3f}; "
              f"correlation of error and confidence {np.corrcoef(d, c)[0, 1]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
