"""Completion through long occlusions on a simulated rig (docs/results.md, "Synchronized camera rigs").

    python benchmarks/rig_occlusion.py [--seeds 4] [--frames 150] [--joints wrist|arm]
                                       [--lengths 10 20 30 40] [--cases missing wrong] [--no-fill]

A simulated 5-camera ring rig (:mod:`mvm.sim.rig_scene`: people playing real motions, the
default detector errors, no lens distortion). Every person loses one arm's wrist (``--joints
arm``: its elbow and wrist) for a stretch of each of ``--lengths`` instants. Four cases:

- ``missing``: the joint's keypoints are dropped in all the views but 0 or 1 of them (drawn
  per stretch), as a body or a table hides a limb from most of a rig;
- ``wrong`` (as on Shelf): the joint is seen at its place in 1 or 2 views (a quarter to a
  third of them) and reported in the others anyway, each at the projection of a point 20 to
  40 cm from the truth (a direction drawn per view and stretch), as a detector confuses a
  hidden hand with something near it;
- ``ghost``: as ``wrong``, but the views that do not see the joint all report one point 20 to
  40 cm from it (one direction per stretch): they agree on a thing that is not the joint (the
  other hand, a prop), and outnumber the views that see it.
- ``other-arm``: as ``ghost``, with one displacement for the elbow and the wrist (``--joints
  arm``): the views agree on another arm, whose forearm is as long.

The rig's time steps run as ``mvm rig reconstruct`` runs them
(:func:`mvm.rig.reconstruct_rig.track_and_complete`).

Printed, per case, stretch length and number of views that see the joint at its place: the
MPJPE of the hidden joints the fill completed (interpolated or inferred), of those that came out
observed (wrong ones kept), of all of them, and of the observed joints around them (the elbow and
shoulder of a hidden wrist over the same stretch), and the share of the hidden joints more than
10 cm off (``FAR_M``); beside them two oracles that are given the
truth at the stretch's ends (the joint and its parent at the two instants either side, the
parent through the stretch, the bone's true length): the same fit
(:func:`mvm.core.gap_fit.fit_gaps`, no prior) with the rays of only the views that see the
joint at its place, and with no rays (the motion alone: what no view can tell). The oracle's
rays have the default deviation (:data:`mvm.rig.occlusions.RAY_SIGMA_M`, 2 cm), not the one the
capture measures (:func:`mvm.rig.occlusions.ray_sigma`; the simulated detector's, against the
true joints, is 1.3 cm): with that, the oracle was up to 9 mm worse, a softer reference.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from mvm.core.completion import OBSERVED
from mvm.core.config import Config
from mvm.core.gap_fit import fit_gaps
from mvm.core.keypoints import INDEX
from mvm.metrics.poses import match_persons
from mvm.rig.instants import reconstruct_instants, rig_poses
from mvm.rig.occlusions import ACC_SIGMA_FACTOR, BONE_SIGMA, LIMB_PASSES, RAY_GATE_M, RAY_SIGMA_M, rays
from mvm.rig.options import RigOptions
from mvm.rig.reconstruct_rig import completion_prior, instants_config, rig_config, track_and_complete
from mvm.sim.rig_scene import RigSimConfig, simulate_rig

#: A person is the true person of smallest MPJPE within this distance. [m]
MATCH_M = 0.5
SIDES = ("left", "right")
#: The views left seeing the joint at its place, drawn per stretch, in each case.
SEEN = {"missing": (0, 1), "wrong": (1, 2), "ghost": (1, 2), "other-arm": (1, 2)}
PARENT = {j: p for joints in LIMB_PASSES for j, p in joints}
COLUMNS = ("filled", "kept observed", "all hidden", "oracle: right views", "oracle: motion only", "around")
#: A hidden joint this far off counts in the last column: about the failures a limb's PCP
#: counts (the mean error of its two ends within half its length: 12-15 cm for an arm's bones). [m]
FAR_M = 0.1


def _offset(rng: np.random.Generator) -> np.ndarray:
    """``(3,)`` a displacement of 20 to 40 cm in a random direction. [m]"""
    offset = rng.normal(size=3)
    return offset * rng.uniform(0.2, 0.4) / np.linalg.norm(offset)


def _report_off(sim, rows: np.ndarray, v: int, g: int, j: int, offset: np.ndarray) -> None:
    """The keypoints ``rows`` of joint ``j`` of person ``g`` in view ``v`` moved (in place) to
    the projection of the truth displaced by ``offset: (3,)``."""
    sel = np.flatnonzero(rows & (sim.camera == v))
    point = sim.poses3d[sim.frame[sel], g, j] + offset                              # (k, 3)
    uvw = np.einsum("ij,kj->ki", sim.calibration.cameras.P[v], np.concatenate([point, np.ones((len(sel), 1))], 1))
    sim.keypoints[sel, j, :2] = uvw[:, :2] / uvw[:, 2:]
    sim.keypoints[sel, j, 2] = np.maximum(sim.keypoints[sel, j, 2], 0.5)


def occlude(sim, rng: np.random.Generator, joints: str, length: int, case: str = "missing") -> list[tuple]:
    """Hide one arm of every person of ``sim`` (in place, in ``sim.keypoints``) for ``length``
    instants from all the views but those still seeing it (:data:`SEEN`): dropped (``missing``)
    or reported 20 to 40 cm off (``wrong``: each view elsewhere; ``ghost``: all at one point;
    ``other-arm``: all at one point, moved alike for the elbow and the wrist).

    Returns the stretches: ``(person, joints, first instant, views seeing them)``."""
    S, G = sim.poses3d.shape[:2]
    V = len(sim.calibration.cameras.names)
    stretches = []
    for g in range(G):
        side = SIDES[rng.integers(2)]
        js = [INDEX[f"{side}_wrist"]] + ([INDEX[f"{side}_elbow"]] if joints == "arm" else [])
        t0 = int(rng.integers(10, S - length - 10))
        keep = rng.permutation(V)[:rng.choice(SEEN[case])]
        rows = (sim.person == g) & (sim.frame >= t0) & (sim.frame < t0 + length) & ~np.isin(sim.camera, keep)
        arm = _offset(rng) if case == "other-arm" else None
        for j in js:
            if case == "missing":
                sim.keypoints[rows, j] = 0.0
            else:
                shared = arm if arm is not None else _offset(rng) if case == "ghost" else None
                for v in np.setdiff1d(np.arange(V), keep):
                    _report_off(sim, rows, v, g, j, _offset(rng) if shared is None else shared)
        stretches.append((g, js, t0, keep))
    return stretches


def oracle(sim, g: int, j: int, t0: int, n: int, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(n,)`` errors of the fills of joint ``j`` of person ``g`` over ``t0 .. t0 + n`` given the
    truth at the stretch's ends and its parent's through it: with the rays of the views
    ``keep`` (those that see it at its place), and with none."""
    P = sim.poses3d[:, g]
    off = P[:, j] - P[:, PARENT[j]]                                                 # (S, 3)
    bone = np.median(np.linalg.norm(off, axis=-1))
    acc = off[2:] - 2 * off[1:-1] + off[:-2]
    sigma = ACC_SIGMA_FACTOR * np.sqrt(np.mean(acc ** 2))
    V = len(sim.calibration.cameras.names)
    xy, conf = np.zeros((n, V, 1, 2)), np.zeros((n, V, 1))
    sel = np.flatnonzero((sim.person == g) & (sim.frame >= t0) & (sim.frame < t0 + n) & np.isin(sim.camera, keep))
    xy[sim.frame[sel] - t0, sim.camera[sel], 0] = sim.keypoints[sel, j, :2]
    conf[sim.frame[sel] - t0, sim.camera[sel], 0] = sim.keypoints[sel, j, 2]
    errors = []
    for c in (conf, 0 * conf):
        origin, direction = rays(xy, c, sim.calibration.cameras)                   # (n, V, 1, 3)
        o = origin[:, :, 0] - P[t0:t0 + n, PARENT[j]][:, None]
        r, _, _ = fit_gaps(off[None, t0 - 2:t0], off[None, t0 + n:t0 + n + 2], [bone], [sigma], [BONE_SIGMA * bone],
                           ray_origin=o[None], ray_direction=direction[None, :, :, 0], sigma_ray=RAY_SIGMA_M,
                           gate=RAY_GATE_M)
        errors.append(np.linalg.norm(r[0] - off[t0:t0 + n], axis=-1))
    return errors[0], errors[1]


def run(seed: int, frames: int, joints: str, length: int, case: str, config: Config, prior,
        options: RigOptions) -> dict:
    """Errors (m) of one simulated capture: ``{views seeing: {column: [errors]}}`` (:data:`COLUMNS`)."""
    sim = simulate_rig(RigSimConfig(cameras=5, people=3, frames=frames, distortion=0.0, seed=seed))
    stretches = occlude(sim, np.random.default_rng(1000 + seed), joints, length, case)
    det = rig_poses(sim.keypoints, sim.frame, sim.camera, sim.score)
    cameras = sim.calibration.cameras
    persons = reconstruct_instants(cameras, det, instants_config(config), prior)
    _, persons, X, flags = track_and_complete(persons, options, prior, config, det, cameras)
    out = {}
    for g, js, t0, keep in stretches:
        cols = out.setdefault(len(keep), {c: [] for c in COLUMNS})
        around = [INDEX[f"{s}_{k}"] for s in SIDES for k in ("elbow", "shoulder")
                  if INDEX[f"{s}_wrist"] in js and INDEX[f"{s}_{k}"] not in js]
        for j in js:
            with_rays, motion = oracle(sim, g, j, t0, length, keep)
            cols["oracle: right views"] += with_rays.tolist()
            cols["oracle: motion only"] += motion.tolist()
        for t in range(t0, t0 + length):
            rows = np.flatnonzero(persons.instant == t)
            for p, gg in match_persons(X[rows], sim.poses3d[t], MATCH_M):
                if gg != g:
                    continue
                d = np.linalg.norm(X[rows[p]] - sim.poses3d[t, g], axis=-1)
                f = np.asarray(flags[rows[p]])
                for j in js:
                    cols["all hidden"].append(d[j])
                    cols["kept observed" if f[j] == OBSERVED else "filled"].append(d[j])
                cols["around"] += [d[k] for k in around if f[k] == OBSERVED]
    return out


def table(args, config: Config, prior, options: RigOptions) -> list[str]:
    """The table's rows (markdown), one per case, stretch length and number of views seeing."""
    lines = []
    for case in args.cases:
        for length in args.lengths:
            total = {}
            for seed in range(args.seeds):
                for k, cols in run(seed, args.frames, args.joints, length, case, config, prior, options).items():
                    for c, v in cols.items():
                        total.setdefault(k, {c: [] for c in COLUMNS})[c] += v
            for k in sorted(total):
                cells = [f"{1000 * np.mean(v):.1f} ({len(v)})" if v else "-" for v in total[k].values()]
                hidden = np.asarray(total[k]["all hidden"])
                far = f"{100 * np.mean(hidden > FAR_M):.1f}" if len(hidden) else "-"
                lines.append(f"| {case} | {length} | {k} | " + " | ".join(cells) + f" | {far} |")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--joints", choices=("wrist", "arm"), default="wrist")
    parser.add_argument("--lengths", type=int, nargs="+", default=[10, 20, 30, 40])
    parser.add_argument("--cases", nargs="+", choices=tuple(SEEN), default=None,
                        help="Default: all (other-arm only with --joints arm, where it differs from ghost).")
    parser.add_argument("--no-fill", action="store_true", help="Without the occlusion fill (occlusion_max_gap = 0).")
    args = parser.parse_args()
    if min(args.lengths) < 1 or max(args.lengths) > args.frames - 22:
        parser.error(f"--lengths: from 1 to {args.frames - 22} instants for {args.frames} frames")
    args.cases = args.cases or [case for case in SEEN if args.joints == "arm" or case != "other-arm"]
    config = rig_config()
    options = RigOptions(frame_rate=30.0, occlusion_max_gap=0 if args.no_fill else RigOptions().occlusion_max_gap)
    print(f"5 cameras, 3 people, {args.frames} instants, {args.seeds} seeds, hidden: {args.joints}, "
          f"{'without' if args.no_fill else 'with'} the occlusion fill; MPJPE mm (joint-instants)")
    print("| case | instants | views seeing it | " + " | ".join(COLUMNS) + f" | hidden > {100 * FAR_M:.0f} cm % |")
    print("|---" * (len(COLUMNS) + 4) + "|")
    print("\n".join(table(args, config, completion_prior(config), options)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
