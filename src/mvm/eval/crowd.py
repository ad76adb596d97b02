"""The frozen-crowd benchmark: scenes as hard as real Mannequin Challenge crowds (the 'crowd'
preset of :mod:`mvm.sim.simulate`, with the camera and the crowd drawn in the real ranges),
each reconstructed by the methods under test and by the oracle (the true grouping, plain
RANSAC/DLT triangulation, no refinement), geometry only and with appearance. No I/O here:
``benchmarks/crowd.py`` prints the tables and writes the files.

Every row reports pairwise matching precision and recall, the persons estimated, found (within
:data:`mvm.metrics.poses.MATCH_DISTANCE_M` of a true person) and true, MPJPE (mean and median over
the persons found), E_R (px, beside the paper's 14.6 px on real videos) and the time, for the
method and for the oracle on the same scene.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from mvm.core.config import Config
from mvm.core.reconstruct import reconstruct
from mvm.metrics.poses import MATCH_DISTANCE_M, match_persons, matching_precision_recall, person_errors
from mvm.sim.simulate import SimConfig, crowd_radius, simulate

#: The paper's mean reprojection error on its real videos (Table 1, MVM). [px]
PAPER_E_R_PX = 14.6
#: The ranges real frozen crowds span (the issue's benchmark): people, frames, arc (deg),
#: camera distance from the crowd's centre (m), camera (eye) height (m).
CROWD_RANGES = {"people": (8, 15), "frames": (100, 250), "arc_deg": (40.0, 90.0),
                "camera_distance": (4.0, 7.0), "camera_height": (1.4, 1.8)}
#: False poses, as a fraction of the true poses (per view: this times the people).
FALSE_POSE_FRACTION = 0.1


def crowd_config(seed: int, **fixed) -> SimConfig:
    """A 'crowd' scene: people, frames, arc, camera distance and height drawn uniformly in
    :data:`CROWD_RANGES` from ``seed`` (unless ``fixed``); the crowd's disc and the false-pose
    rate follow the number of people. Other ``fixed`` settings are passed to the preset."""
    rng = np.random.default_rng([seed, 13])
    drawn = {}
    for key, (lo, hi) in CROWD_RANGES.items():
        value = rng.integers(lo, hi + 1) if isinstance(lo, int) else rng.uniform(lo, hi)
        drawn[key] = fixed.pop(key, type(lo)(value))
    people = int(drawn["people"])
    return SimConfig.preset("crowd", **drawn, crowd_radius=crowd_radius(people),
                            false_pose_rate=FALSE_POSE_FRACTION * people, seed=seed, **fixed)


def pelvis_spacing(poses3d: np.ndarray) -> np.ndarray:
    """Horizontal distance of every person's pelvis to its nearest neighbour's.
    ``poses3d: (G, 17, 3)`` -> ``(G,)`` metres."""
    pelvis = poses3d[:, [11, 12], :2].mean(1)
    d = np.linalg.norm(pelvis[:, None] - pelvis[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return d.min(1)


def true_groups(person: np.ndarray) -> list[np.ndarray]:
    """The oracle's grouping: the poses of every true person. ``person: (N,)`` (-1: false)."""
    return [np.flatnonzero(person == g) for g in range(int(person.max(initial=-1)) + 1)
            if (person == g).any()]


def score(result, truth, seconds: float) -> dict:
    """The row of one reconstruction of a simulated scene (lengths in mm)."""
    members = result.persons.members
    precision, recall = matching_precision_recall(members, truth.person)
    X = result.persons.keypoints3d
    pairs = match_persons(X, truth.poses3d, MATCH_DISTANCE_M)
    mpjpe, _ = person_errors(X, truth.poses3d, pairs)
    return {"precision": precision, "recall": recall, "persons": len(X), "found": len(pairs),
            "true": len(truth.poses3d),
            "mpjpe_mm": 1000 * float(np.mean(mpjpe)) if len(mpjpe) else float("nan"),
            "mpjpe_median_mm": 1000 * float(np.median(mpjpe)) if len(mpjpe) else float("nan"),
            "E_R_px": result.metrics["E_R_px"], "seconds": seconds}


def _timed(scene, config: Config, groups=None):
    t = time.perf_counter()
    result = reconstruct(scene, config, groups=groups)
    return result, time.perf_counter() - t


def run_scene(sim: SimConfig, methods: Iterable[tuple[str, Config]], appearance: Iterable[bool] = (False, True),
              label: str = "", bank_poses=None) -> list[dict]:
    """Rows of every method (``(name, Config)``) on the scene ``sim``, geometry only and/or
    with appearance, each beside the oracle on the same scene (``oracle_*`` columns)."""
    scene, truth = simulate(sim, bank_poses)
    methods = list(methods)
    base = methods[0][1] if methods else Config()
    result, seconds = _timed(scene, base.replace(refine=False), true_groups(truth.person))
    oracle = score(result, truth, seconds)
    scene_info = {"scene": label or f"seed{sim.seed}", "people": sim.people, "frames": sim.frames,
                  "arc_deg": round(sim.arc_deg, 1), "camera_distance": round(sim.camera_distance, 2),
                  "camera_height": round(sim.camera_height, 2), "poses": len(scene.poses),
                  "false_poses": int((truth.person < 0).sum()),
                  "closest_pair_m": round(float(pelvis_spacing(truth.poses3d).min()), 3) if sim.people > 1 else None}
    rows = []
    for use_appearance in appearance:
        for name, config in methods:
            result, seconds = _timed(scene, config.replace(use_appearance=use_appearance))
            rows.append({**scene_info, "method": name,
                         "cues": "geometry + appearance" if use_appearance else "geometry",
                         **score(result, truth, seconds), **{f"oracle_{k}": v for k, v in oracle.items()}})
    return rows


def default_methods() -> list[tuple[str, Config]]:
    """The methods under test: the paper's association and, where the configuration offers
    it, the association consistent in 3D (``Config.association``)."""
    if "association" in Config.__dataclass_fields__:
        return [("paper", Config().replace(association="paper")), ("3d", Config().replace(association="3d"))]
    return [("paper", Config())]


#: The crowd scenes of the main table (seeds; people, frames, arc and camera drawn from them),
#: and the scene of the issue's second row (10 people, 250 frames, 90°).
SUITE_SEEDS = (0, 1, 2, 3, 4, 5)
LONG_TOUR = dict(people=10, frames=250, arc_deg=90.0)
#: The sweeps: crowd size at a 60° arc, arc at 10 people (150 frames, seeds 100 + i).
SWEEPS = {"people": (5, 8, 10, 12, 15), "arc_deg": (20.0, 40.0, 60.0, 90.0, 120.0)}
SWEEP_BASE = dict(people=10, frames=150, arc_deg=60.0, camera_distance=5.5, camera_height=1.6)
#: Quick mode (CI): one small crowd and two values per sweep on short tours.
QUICK_SCENE = dict(people=8, frames=100, arc_deg=60.0)
QUICK_SWEEPS = {"people": (5, 10), "arc_deg": (20.0, 90.0)}
QUICK_SWEEP_BASE = dict(people=6, frames=40, arc_deg=60.0, camera_distance=5.5, camera_height=1.6)


@dataclass
class CrowdResult:
    """Rows of the crowd scenes (``rows``) and of the sweeps (``sweep_rows``, with ``axis``
    and ``value``)."""

    rows: list[dict]
    sweep_rows: list[dict]


def run_crowd(quick: bool = False, methods: Iterable[tuple[str, Config]] | None = None, bank_poses=None,
              progress: Callable[[str], None] | None = None) -> CrowdResult:
    """The whole benchmark: the crowd scenes geometry only and with appearance, and the
    sweeps over crowd size and arc (geometry only), every method beside the oracle."""
    methods = list(methods or default_methods())
    say = progress or (lambda message: None)
    scenes = ([("crowd_quick", crowd_config(0, **QUICK_SCENE))] if quick else
              [(f"crowd{seed}", crowd_config(seed)) for seed in SUITE_SEEDS]
              + [("crowd_long", crowd_config(10, **LONG_TOUR))])
    rows = []
    for label, sim in scenes:
        say(f"{label}: {sim.people} people, {sim.frames} frames, {sim.arc_deg:.0f} deg")
        rows += run_scene(sim, methods, (False, True), label, bank_poses)
    sweep_rows = []
    base = QUICK_SWEEP_BASE if quick else SWEEP_BASE
    for axis, values in (QUICK_SWEEPS if quick else SWEEPS).items():
        for i, value in enumerate(values):
            sim = crowd_config(100 + i, **{**base, axis: value})
            say(f"sweep {axis} = {value}")
            sweep_rows += [{"axis": axis, "value": value, **row}
                           for row in run_scene(sim, methods, (False,), f"{axis}={value}", bank_poses)]
    return CrowdResult(rows, sweep_rows)


#: Columns of the crowd tables: (key, header, decimals).
COLUMNS = (("scene", "scene", 0), ("people", "people", 0), ("frames", "frames", 0), ("arc_deg", "arc °", 0),
           ("method", "method", 0), ("cues", "cues", 0), ("precision", "precision", 3), ("recall", "recall", 3),
           ("found_true", "persons / found / true", 0), ("mpjpe_mm", "MPJPE mm", 1),
           ("mpjpe_median_mm", "median mm", 1), ("E_R_px", "E_R px (paper 14.6)", 1), ("seconds", "s", 1),
           ("oracle_precision", "oracle precision", 3), ("oracle_recall", "oracle recall", 3),
           ("oracle_found_true", "oracle persons / found / true", 0), ("oracle_mpjpe_mm", "oracle MPJPE mm", 1),
           ("oracle_mpjpe_median_mm", "oracle median mm", 1),
           ("oracle_E_R_px", "oracle E_R px", 1), ("oracle_seconds", "oracle s", 1))
SWEEP_COLUMNS = (("axis", "axis", 0), ("value", "value", 0)) + COLUMNS[4:]


def table_rows(rows: list[dict]) -> list[dict]:
    """``rows`` with the persons columns as text (estimated / found / true)."""
    return [{**r, "found_true": f"{r['persons']} / {r['found']} / {r['true']}",
             "oracle_found_true": f"{r['oracle_persons']} / {r['oracle_found']} / {r['oracle_true']}"} for r in rows]


def summary(rows: list[dict]) -> list[dict]:
    """One line per method and cues over all ``rows``: pooled precision and recall (means),
    persons estimated / found / true (sums), scenes with persons = true, MPJPE (mean of the
    scenes' means, median of their medians), E_R and times (means), oracle alike."""
    out = []
    for key in dict.fromkeys((r["method"], r["cues"]) for r in rows):
        sel = [r for r in rows if (r["method"], r["cues"]) == key]
        mean = lambda k: float(np.nanmean([r[k] for r in sel]))  # noqa: E731, B023 (used in this iteration only)
        out.append({"method": key[0], "cues": key[1], "scenes": len(sel), "precision": mean("precision"),
                    "recall": mean("recall"),
                    "found_true": f"{sum(r['persons'] for r in sel)} / {sum(r['found'] for r in sel)} / "
                                  f"{sum(r['true'] for r in sel)}",
                    "exact_scenes": sum(r["persons"] == r["true"] == r["found"] for r in sel),
                    "mpjpe_mm": mean("mpjpe_mm"),
                    "mpjpe_median_mm": float(np.nanmedian([r["mpjpe_median_mm"] for r in sel])),
                    "E_R_px": mean("E_R_px"), "seconds": mean("seconds"),
                    "oracle_precision": mean("oracle_precision"), "oracle_recall": mean("oracle_recall"),
                    "oracle_found_true": f"{sum(r['oracle_persons'] for r in sel)} / "
                                         f"{sum(r['oracle_found'] for r in sel)} / "
                                         f"{sum(r['oracle_true'] for r in sel)}",
                    "oracle_mpjpe_mm": mean("oracle_mpjpe_mm"),
                    "oracle_mpjpe_median_mm": float(np.nanmedian([r["oracle_mpjpe_median_mm"] for r in sel])),
                    "oracle_E_R_px": mean("oracle_E_R_px"), "oracle_seconds": mean("oracle_seconds")})
    return out


SUMMARY_COLUMNS = (("method", "method", 0), ("cues", "cues", 0), ("scenes", "scenes", 0),
                   ("precision", "precision", 3), ("recall", "recall", 3),
                   ("found_true", "persons / found / true", 0), ("exact_scenes", "scenes exact", 0)) + COLUMNS[9:]
