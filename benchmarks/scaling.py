"""How the reconstruction's cost grows with the length of the video and the size of the crowd.

    python benchmarks/scaling.py [--quick] [--max-frames 1200] [--people 5,10,20] [--repeat 3]
                                 [--preset realistic] [--arc 120] [--out DIR]

Scenes: ``simulate(SimConfig.preset(preset, people=p, frames=f, arc_deg=arc, seed=seed))`` for
frames 150, 300, 600, 1,200, 2,400, 3,600 (doubling, then the two-minute video) and 5, 10, 20
people. Each size is written as a scene directory and reconstructed in a process of its own, as
``mvm reconstruct`` does (:func:`mvm.scenes.reconstruct_dir`, default settings): the table gives
that process's wall time (start-up included) and CPU time (user + system: what a loaded machine
inflates least; with ``--repeat``, the least of several runs, made in rounds over all the
sizes so that a slow spell of the machine weighs on every size alike), its peak resident memory
(``VmHWM``), the time of every stage,
and pairwise precision / recall, persons estimated / found / true and MPJPE, beside the oracle on
the same scene (the true grouping, RANSAC/DLT triangulation, no refinement, as
:mod:`mvm.eval.crowd` scores it; also in a process of its own). Below the table: the growth of
time (wall and CPU) and memory per doubling of the frames, for every crowd size (with
``--repeat``, also the median and worst over the rounds of the wall time's growth).

``--quick``: 10 people, 150 to 600 frames. ``--max-frames`` drops the longer videos.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

FRAMES = (150, 300, 600, 1200, 2400, 3600)
PEOPLE = (5, 10, 20)
QUICK_FRAMES = (150, 300, 600)
QUICK_PEOPLE = (10,)
STAGES = ("matching_s", "triangulation_s", "association_s", "refinement_s")


def run_child(scene_dir: Path, mode: str) -> dict:
    """Reconstruct ``scene_dir`` in a child process (``mode``: ``method`` or ``oracle``): its
    JSON row, with ``process_s`` (wall time from its spawn to its reconstruction written),
    ``cpu_s`` (its user + system time by then) and ``peak_mib`` (its peak resident memory by
    then; :func:`child`); those of the whole process, from ``wait4``, where it failed."""
    with tempfile.TemporaryFile("w+") as out:
        t = time.perf_counter()
        proc = subprocess.Popen([sys.executable, __file__, "--child", mode, str(scene_dir)], stdout=out,
                                env={**os.environ, "OMP_NUM_THREADS": "1", "SCALING_START": repr(time.time())})
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t
        out.seek(0)
        text = out.read()
    measured = {"process_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "peak_mib": usage.ru_maxrss / 1024}
    if proc.returncode != 0:
        return {"error": f"exit {proc.returncode}", **measured}
    return {**measured, **json.loads(text.strip().splitlines()[-1])}


def best_run(rows: list[dict]) -> dict:
    """The first of several runs of one size, with the least wall and CPU time of all (on a
    loaded machine the others measure the load) and every run's wall time (``runs_s``)."""
    return {**rows[0], "process_s": min(r["process_s"] for r in rows), "cpu_s": min(r["cpu_s"] for r in rows),
            "runs_s": [r["process_s"] for r in rows]}


def peak_mib() -> float:
    """This process's peak resident memory since it started (``VmHWM``), MiB. Not ``ru_maxrss``:
    a process spawned by ``vfork`` counts in it the parent's memory before its ``exec``, here
    the scenes the parent simulated."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def child(mode: str, scene_dir: str) -> None:
    """The body of a child process: reconstruct, then score against the truth, and print one
    JSON line. Its time (since the parent spawned it, ``SCALING_START``), CPU time and peak
    memory are taken when the reconstruction is written, before the scoring imports anything."""
    import resource

    from mvm.core.config import Config

    if mode == "method":
        from mvm.scenes import reconstruct_dir

        result = reconstruct_dir(scene_dir, Config())
    else:
        import numpy as np

        from mvm.core.reconstruct import reconstruct
        from mvm.eval.crowd import true_groups
        from mvm.io.ground_truth import read_ground_truth
        from mvm.io.layout import SceneLayout
        from mvm.io.scene_dir import read_scene

        scene = read_scene(scene_dir)
        truth = read_ground_truth(SceneLayout(scene_dir).truth)
        person = dict(zip(range(1, len(truth.person) + 1), truth.person))
        true_person = [person[int(i)] for i in scene.poses.ids]
        result = reconstruct(scene, Config(refine=False), groups=true_groups(np.asarray(true_person)))
    usage = resource.getrusage(resource.RUSAGE_SELF)
    spent = {"process_s": time.time() - float(os.environ["SCALING_START"]), "cpu_s": usage.ru_utime + usage.ru_stime,
             "peak_mib": peak_mib()}
    from mvm.eval.demo import evaluate
    from mvm.io.ground_truth import read_ground_truth
    from mvm.io.layout import SceneLayout

    report = evaluate(result, read_ground_truth(SceneLayout(scene_dir).truth))
    print(json.dumps({k: report[k] for k in ("precision", "recall", "mpjpe_mm", "persons_found",
                                             "persons_estimated", "persons_true", "poses")}
                     | {k: float(v) for k, v in report["timings"].items()} | spent))


def write_size(people: int, frames: int, args, work: Path) -> dict:
    """Simulate one size and write it as a scene directory: its row, without measurements."""
    from mvm.io.ground_truth import write_simulation
    from mvm.sim.simulate import SimConfig, simulate

    sim = SimConfig.preset(args.preset, people=people, frames=frames, arc_deg=args.arc, seed=args.seed)
    scene, truth = simulate(sim)
    scene_dir = work / f"p{people}_f{frames}" / "scene"
    write_simulation(scene_dir, scene, truth, sim)
    return {"people": people, "frames": frames, "poses": len(scene.poses), "scene": str(scene_dir)}


def measure(rows: list[dict], repeat: int, oracle: bool) -> None:
    """Reconstruct every size ``repeat`` times, by the method, in rounds: each round runs every
    size once, so a slow spell of the machine weighs on all sizes alike rather than on one;
    then the oracle once. Fills each row's ``method`` (:func:`best_run`) and ``oracle``."""
    runs = [[] for _ in rows]
    for _ in range(max(repeat, 1)):
        for row, found in zip(rows, runs):
            found.append(run_child(Path(row["scene"]), "method"))
            print(f"{row['people']} people, {row['frames']} frames: {json.dumps(found[-1])}", file=sys.stderr,
                  flush=True)
    for row, found in zip(rows, runs):
        row["method"] = best_run(found)
        row["oracle"] = run_child(Path(row["scene"]), "oracle") if oracle else {}


def _fmt(value, digits: int) -> str:
    return "—" if value is None or value != value else f"{value:,.{digits}f}"


def _growth(a: dict, b: dict) -> str:
    """Wall time, CPU time and memory of row ``b`` over row ``a``, per doubling of the frames;
    with several rounds, also the median over the rounds of the wall time's growth in each."""
    doublings = math.log2(b["frames"] / a["frames"])
    ratio = {k: (b["method"][k] / a["method"][k]) ** (1 / doublings) if a["method"].get(k) else math.nan
             for k in ("process_s", "cpu_s", "peak_mib")}
    text = f"×{ratio['process_s']:.2f} time, ×{ratio['cpu_s']:.2f} CPU, ×{ratio['peak_mib']:.2f} memory"
    rounds = [(y / x) ** (1 / doublings) for x, y in zip(a["method"].get("runs_s", []), b["method"].get("runs_s", []))]
    if len(rounds) > 1:
        text += f" (time per round: median ×{statistics.median(rounds):.2f}, worst ×{max(rounds):.2f})"
    return text


def table(rows: list[dict]) -> str:
    """The scaling table (markdown) and the growth per doubling of the frames."""
    lines = ["| people | frames | 2D poses | process s | CPU s | peak MiB | matching / triangulation / association / "
             "refinement s | precision | recall | persons est. / found / true | MPJPE mm | oracle precision / "
             "recall | oracle MPJPE mm |",
             "|---:|---:|---:|---:|---:|---:|---|---:|---:|---|---:|---|---:|"]
    for r in rows:
        m, o = r["method"], r["oracle"]
        if "error" in m:
            lines.append(f"| {r['people']} | {r['frames']:,} | {r['poses']:,} | {m['error']} | | "
                         f"{_fmt(m['peak_mib'], 0)} | | | | | | | |")
            continue
        stages = " / ".join(_fmt(m.get(k, 0.0), 2) for k in STAGES)
        lines.append(f"| {r['people']} | {r['frames']:,} | {r['poses']:,} | {_fmt(m['process_s'], 1)} | "
                     f"{_fmt(m.get('cpu_s'), 1)} | {_fmt(m['peak_mib'], 0)} | {stages} | "
                     f"{m['precision']:.4f} | {m['recall']:.4f} | "
                     f"{m['persons_estimated']} / {m['persons_found']} / {m['persons_true']} | "
                     f"{_fmt(m['mpjpe_mm'], 1)} | "
                     + (f"{o['precision']:.4f} / {o['recall']:.4f} | {_fmt(o['mpjpe_mm'], 1)} |"
                        if o and "error" not in o else "— | — |"))
    lines += ["", "Growth per doubling of the frames (wall time, CPU time, memory; from the row before):", ""]
    for people in dict.fromkeys(r["people"] for r in rows):
        sel = [r for r in rows if r["people"] == people and "error" not in r["method"]]
        steps = [f"{a['frames']}→{b['frames']}: {_growth(a, b)}" for a, b in zip(sel, sel[1:])]
        if len(sel) > 1:
            steps.append(f"on average {sel[0]['frames']}→{sel[-1]['frames']}: {_growth(sel[0], sel[-1])} per doubling")
        lines.append(f"- {people} people: " + ("; ".join(steps) or "—"))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10 people, 150-600 frames.")
    parser.add_argument("--max-frames", type=int, default=None, help="Drop the videos longer than this.")
    parser.add_argument("--people", default=None, help="Crowd sizes, comma-separated (default 5,10,20).")
    parser.add_argument("--frames", default=None, help="Video lengths, comma-separated (default 150-3600).")
    parser.add_argument("--preset", default="realistic", help="Simulator preset (detector errors).")
    parser.add_argument("--arc", type=float, default=120.0, help="Angle of the tour, degrees.")
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--no-oracle", action="store_true", help="Skip the oracle (half the time).")
    parser.add_argument("--repeat", type=int, default=1, help="Reconstruct each size this many times, in rounds "
                                                              "over all sizes: the least wall and CPU time.")
    parser.add_argument("--out", default=None, help="Write scaling.md and scaling.json into this folder.")
    parser.add_argument("--child", nargs=2, metavar=("MODE", "SCENE_DIR"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(*args.child)
        return
    people = [int(p) for p in args.people.split(",")] if args.people else (QUICK_PEOPLE if args.quick else PEOPLE)
    frames = [int(f) for f in args.frames.split(",")] if args.frames else (QUICK_FRAMES if args.quick else FRAMES)
    frames = [f for f in frames if args.max_frames is None or f <= args.max_frames]
    with tempfile.TemporaryDirectory(prefix="mvm-scaling-") as tmp:
        rows = [write_size(p, f, args, Path(tmp)) for p in people for f in frames]
        measure(rows, args.repeat, not args.no_oracle)
    for row in rows:
        del row["scene"]                                       # removed with the folder
    text = table(rows)
    print(text)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "scaling.md").write_text(text + "\n")
        (out / "scaling.json").write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
