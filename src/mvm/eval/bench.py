"""The paper's Tables 1 and 2 on simulated clips with ground truth, sweeps of difficulty, and
the cost of every matching method.

Every row evaluates one grouping method on one affinity over one clip: the paper's proxy
metrics (E_R, outliers, |G_k|, with and without RANSAC) and the ones only ground truth allows
(pairwise matching precision / recall / F1, persons recovered, MPJPE, PA-MPJPE), plus the
matching time. Tables average the rows of a method over the clips. No I/O here: the script
``benchmarks/paper_tables.py`` writes the files.
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace

import numpy as np
from threadpoolctl import threadpool_limits

from mvm.core.config import Config
from mvm.core.matching.baselines import BaselineConfig
from mvm.core.matching.registry import affinity_matrix, get_matcher
from mvm.core.reconstruct import reconstruct
from mvm.metrics.poses import MATCH_DISTANCE_M, match_persons, matching_precision_recall, pose_errors
from mvm.sim.simulate import SimConfig, simulate

log = logging.getLogger(__name__)

#: Dong et al.'s method runs only on clips shorter than this, as in the paper. [frames]
DONG_MAX_FRAMES = 50


@dataclass(frozen=True)
class Method:
    """A row label of the tables: a grouping method on an affinity."""

    label: str
    matcher: str
    affinity: str


HUNGARIAN = Method("Hungarian + MSE", "hungarian", "mse")
ARNAB = Method("Arnab et al. (shortest path + MSE)", "shortest_path", "mse")
MVM = Method("MVM (geo + appearance)", "mvm", "geo+app")
DONG = Method("Dong et al. (optimization + our similarity)", "dong", "geo+app")
TABLE1 = (HUNGARIAN, ARNAB, MVM)
TABLE1_SHORT = (DONG, MVM)
TABLE2 = (ARNAB, Method("Shortest path + geo", "shortest_path", "geo"),
          Method("Shortest path + geo + appearance", "shortest_path", "geo+app"),
          Method("MVM + MSE", "mvm", "mse"), Method("MVM + geo", "mvm", "geo"), MVM)
SWEEP_METHODS = (HUNGARIAN, ARNAB, DONG, MVM)

#: Columns of the tables, in order: (key, header, decimals).
COLUMNS = (("clips", "clips", 0), ("E_R_px", "E_R px", 1), ("outliers", "outliers", 1), ("G_k", "|G_k|", 1),
           ("E_R_px_no_ransac", "E_R px w/o RANSAC", 1), ("G_k_no_ransac", "|G_k| w/o RANSAC", 1),
           ("precision", "precision", 3), ("recall", "recall", 3), ("f1", "F1", 3),
           ("recovered", "persons recovered", 2), ("mpjpe_mm", "MPJPE mm", 1), ("pa_mpjpe_mm", "PA-MPJPE mm", 1),
           ("matching_s", "matching s", 3), ("clip_s", "time per clip s", 2))


@dataclass(frozen=True)
class Clip:
    name: str
    sim: SimConfig


def paper_suite(quick: bool = False, trajectories: Iterable[str] = ()) -> list[Clip]:
    """The fixed-seed clips of Tables 1–2: mixed lengths (a third under 50 frames), crowds
    of 4–15, tours of 30–120°, the 'realistic' detector; real camera paths where given."""
    if quick:
        specs = [(20, 3, 45.0), (30, 4, 60.0)]
    else:
        specs = [(30, 4, 30.0), (40, 6, 45.0), (45, 8, 60.0), (60, 10, 40.0), (86, 10, 60.0),
                 (86, 12, 90.0), (120, 8, 120.0), (150, 15, 90.0)]
    paths = list(trajectories)
    clips = []
    for i, (frames, people, arc) in enumerate(specs):
        path = paths[i % len(paths)] if paths and i % 3 == 2 else None
        sim = SimConfig.preset("realistic", frames=frames, people=people, arc_deg=arc, seed=100 + i,
                               crowd_radius=max(2.0, 0.6 * np.sqrt(people)), trajectory=path)
        clips.append(Clip(f"clip{i:02d}_{frames}f_{people}p_{arc:g}deg" + ("_real" if path else ""), sim))
    return clips


def evaluate_groups(scene, truth, groups: list[np.ndarray], config: Config) -> dict:
    """Metrics of one grouping of a simulated scene, reconstructed with and without RANSAC."""
    precision, recall = matching_precision_recall(groups, truth.person)
    with_ransac = reconstruct(scene, config.replace(ransac=True), groups=groups)
    without = reconstruct(scene, config.replace(ransac=False), groups=groups)
    X = with_ransac.persons.keypoints3d
    pairs = match_persons(X, truth.poses3d, MATCH_DISTANCE_M)
    errors = pose_errors(X, truth.poses3d, pairs)
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return {
        "E_R_px": with_ransac.metrics["E_R_px"], "outliers": with_ransac.metrics["outliers"],
        "G_k": with_ransac.metrics["G_k"], "E_R_px_no_ransac": without.metrics["E_R_px"],
        "G_k_no_ransac": without.metrics["G_k"], "precision": precision, "recall": recall, "f1": f1,
        "recovered": len(pairs) / len(truth.poses3d), "persons_true": len(truth.poses3d),
        "persons_estimated": len(with_ransac.persons),
        "mpjpe_mm": 1000 * errors["mpjpe"], "pa_mpjpe_mm": 1000 * errors["pa_mpjpe"],
        "reconstruction_s": with_ransac.timings["total_s"] - with_ransac.timings["matching_s"],
    }


def run_method(scene, truth, method: Method, config: Config, baseline: BaselineConfig,
               evaluate: bool = True) -> dict:
    """Match ``scene`` with ``method`` (timed: affinity + grouping), then evaluate."""
    with threadpool_limits(limits=1, user_api="blas"):
        t = time.perf_counter()
        A = affinity_matrix(scene, config, method.affinity)
        groups = get_matcher(method.matcher)(A, scene.poses.score, scene.poses.view, config, baseline)
        matching_s = time.perf_counter() - t
    row = {"method": method.label, "matcher": method.matcher, "affinity": method.affinity,
           "poses": len(scene.poses), "frames": len(scene.cameras), "groups": len(groups), "matching_s": matching_s}
    if evaluate:
        row.update(evaluate_groups(scene, truth, groups, config))
        row["clip_s"] = matching_s + row["reconstruction_s"]
    return row


def run_clips(clips: list[Clip], methods: Iterable[Method], config: Config, baseline: BaselineConfig,
              bank_poses=None, progress: Callable[[str], None] | None = None) -> list[dict]:
    """One row per (clip, method); Dong's method only on clips under ``DONG_MAX_FRAMES``."""
    rows = []
    methods = list(dict.fromkeys(methods))
    for clip in clips:
        scene, truth = simulate(clip.sim, bank_poses)
        for method in methods:
            if method.matcher == "dong" and clip.sim.frames >= DONG_MAX_FRAMES:
                continue
            if progress:
                progress(f"{clip.name}: {method.label}")
            row = run_method(scene, truth, method, config, baseline)
            rows.append({"clip": clip.name, "short": clip.sim.frames < DONG_MAX_FRAMES, **row})
    return rows


def average(rows: list[dict], methods: Iterable[Method], where: Callable[[dict], bool] = lambda r: True) -> list[dict]:
    """One row per method: the mean of every numeric column over the rows kept by ``where``."""
    table = []
    for method in methods:
        mine = [r for r in rows if r["method"] == method.label and where(r)]
        entry = {"method": method.label, "clips": len(mine)}
        for key, _, _ in COLUMNS[1:]:
            values = np.array([r.get(key, np.nan) for r in mine], dtype=float)
            entry[key] = float(np.nanmean(values)) if np.isfinite(values).any() else float("nan")
        table.append(entry)
    return table


#: The difficulty sweeps: axis -> (SimConfig field or preset, values).
SWEEPS = {
    "parallax_deg": [5.0, 15.0, 30.0, 60.0, 120.0, 180.0],
    "people": [1, 3, 6, 10, 15],
    "detector": ["clean", "realistic", "hard"],
}
QUICK_SWEEPS = {"parallax_deg": [10.0, 60.0], "people": [2, 4], "detector": ["clean", "hard"]}


def sweep(axis: str, values: Iterable, base: SimConfig, methods: Iterable[Method], config: Config,
          baseline: BaselineConfig, seeds: Iterable[int] = (0,), bank_poses=None,
          progress: Callable[[str], None] | None = None) -> list[dict]:
    """Rows of every method at every value of one difficulty ``axis`` ('parallax_deg',
    'people' or 'detector'), on clips derived from ``base`` (frames under 50, so that Dong's
    method runs everywhere)."""
    rows = []
    for value in values:
        for seed in seeds:
            if axis == "parallax_deg":
                sim = replace(base, arc_deg=float(value), seed=seed)
            elif axis == "people":
                sim = replace(base, people=int(value), crowd_radius=max(2.0, 0.6 * np.sqrt(int(value))), seed=seed)
            elif axis == "detector":
                keep = {k: getattr(base, k) for k in ("people", "frames", "arc_deg", "crowd_radius")}
                sim = SimConfig.preset(str(value), seed=seed, **keep)
            else:
                raise ValueError(f"unknown sweep axis {axis!r}; known: {', '.join(SWEEPS)}")
            scene, truth = simulate(sim, bank_poses)
            for method in methods:
                if progress:
                    progress(f"{axis}={value} seed {seed}: {method.label}")
                rows.append({"axis": axis, "value": value, "seed": seed,
                             **run_method(scene, truth, method, config, baseline)})
    return rows


def sweep_table(rows: list[dict], axis: str, metric: str, methods: Iterable[Method]) -> list[dict]:
    """One row per value of ``axis``; one column per method: the mean ``metric``."""
    values = list(dict.fromkeys(r["value"] for r in rows if r["axis"] == axis))
    table = []
    for value in values:
        entry = {axis: value}
        for method in methods:
            v = [r[metric] for r in rows if r["axis"] == axis and r["value"] == value and r["method"] == method.label]
            entry[method.label] = float(np.nanmean(v)) if v and np.isfinite(v).any() else float("nan")
        table.append(entry)
    return table


def speed_comparison(config: Config, baseline: BaselineConfig, frames: int = 86, people: int = 10,
                     seed: int = 7, bank_poses=None) -> dict:
    """MVM against Dong et al. on one paper-like clip: matching times, speed-up, F1 of both."""
    sim = SimConfig.preset("realistic", frames=frames, people=people, arc_deg=60.0, seed=seed,
                           crowd_radius=max(2.0, 0.6 * np.sqrt(people)))
    scene, truth = simulate(sim, bank_poses)
    mvm = run_method(scene, truth, MVM, config, baseline)
    dong = run_method(scene, truth, DONG, config, baseline)
    return {"frames": frames, "people": people, "poses": len(scene.poses),
            "mvm_matching_s": mvm["matching_s"], "dong_matching_s": dong["matching_s"],
            "speedup": dong["matching_s"] / max(mvm["matching_s"], 1e-9),
            "mvm_f1": mvm["f1"], "dong_f1": dong["f1"], "rows": [mvm, dong]}


@dataclass
class BenchResult:
    """Everything the benchmark measured: the per-clip ``rows``, the averaged tables, the
    sweeps' rows and the speed comparison (None in quick mode)."""

    rows: list[dict]
    table1: list[dict]
    table1_short: list[dict]
    table2: list[dict]
    sweep_rows: list[dict]
    speed: dict | None


def run_bench(quick: bool = False, config: Config | None = None, baseline: BaselineConfig | None = None,
              trajectories: Iterable[str] = (), bank_poses=None,
              progress: Callable[[str], None] | None = None) -> BenchResult:
    """Run the whole benchmark (``quick``: two tiny clips, two values per sweep, no speed run)."""
    config = config or Config(refine=False)
    baseline = baseline or (BaselineConfig(dong_max_iterations=100) if quick else BaselineConfig())
    clips = paper_suite(quick, trajectories)
    rows = run_clips(clips, TABLE1 + TABLE1_SHORT + TABLE2, config, baseline, bank_poses, progress)
    table1 = average(rows, TABLE1)
    table1_short = average(rows, TABLE1_SHORT, where=lambda r: r["short"])
    table2 = average(rows, TABLE2)
    base = SimConfig.preset("realistic", frames=16 if quick else 40, people=3 if quick else 8, arc_deg=60.0,
                            crowd_radius=2.0 if quick else 2.4)
    sweeps = QUICK_SWEEPS if quick else SWEEPS
    seeds = (0,) if quick else (0, 1)
    sweep_rows = []
    for axis, values in sweeps.items():
        sweep_rows += sweep(axis, values, base, SWEEP_METHODS, config, baseline, seeds, bank_poses, progress)
    speed = None if quick else speed_comparison(config, baseline, bank_poses=bank_poses)
    return BenchResult(rows, table1, table1_short, table2, sweep_rows, speed)


def markdown_table(table: list[dict], columns: Iterable[tuple[str, str, int]] | None = None) -> str:
    """A Markdown table of ``table`` rows; ``columns``: (key, header, decimals), default all keys."""
    if not table:
        return "(no rows)\n"
    if columns is None:
        columns = [(k, k, 3) for k in table[0]]
    columns = list(columns)

    def cell(value, digits):
        if isinstance(value, str):
            return value
        if value is None or (isinstance(value, float) and not np.isfinite(value)):
            return "–"
        if isinstance(value, (int, np.integer)) or digits == 0:
            return f"{value:.0f}" if isinstance(value, float) else str(value)
        return f"{value:.{digits}f}"

    lines = ["| " + " | ".join(h for _, h, _ in columns) + " |",
             "|" + "|".join("---" if i == 0 else "---:" for i in range(len(columns))) + "|"]
    lines += ["| " + " | ".join(cell(row.get(k), d) for k, _, d in columns) + " |" for row in table]
    return "\n".join(lines) + "\n"
