"""``mvm simulate`` and ``mvm bench``: module-level click commands, registered by ``mvm.cli.main``."""
from __future__ import annotations

import time
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from mvm.errors import InputError

out = Console()


class _InputErrorExit(click.ClickException):
    exit_code = 2

    def show(self, file=None):
        click.echo(f"mvm: error: {self.message}", err=True)


@click.command("simulate")
@click.argument("scene_dir", type=click.Path(file_okay=False))
@click.option("--preset", type=click.Choice(["clean", "realistic", "hard"]), default="realistic", show_default=True,
              help="Detector error model.")
@click.option("--people", default=6, show_default=True, help="Persons in the scene (1-15).")
@click.option("--frames", default=100, show_default=True, help="Frames of the camera tour (20-300).")
@click.option("--arc", "arc_deg", default=60.0, show_default=True, help="Total angle of the tour (deg, 5-180).")
@click.option("--trajectory", type=click.Path(dir_okay=False, exists=True), default=None,
              help="Follow a real camera path (RealEstate10K / MannequinChallenge camera file).")
@click.option("--seed", default=0, show_default=True, help="Random seed.")
@click.option("--render", is_flag=True, help="Also render the frames into SCENE_DIR/frames (for mvm export and training).")
def simulate_cmd(scene_dir, preset, people, frames, arc_deg, trajectory, seed, render):
    """Simulate a mannequin scene into SCENE_DIR; the ground truth goes beside it
    (SCENE_DIR.groundtruth.json)."""
    from mvm.io.ground_truth import write_simulation
    from mvm.sim.simulate import SimConfig, simulate

    try:
        sim = SimConfig.preset(preset, people=people, frames=frames, arc_deg=arc_deg, seed=seed,
                               trajectory=trajectory)
        scene, truth = simulate(sim)
        truth_path = write_simulation(scene_dir, scene, truth, sim)
        if render:
            from pathlib import Path

            from mvm.sim.video import render_frames

            render_frames(Path(scene_dir) / "frames", scene.cameras, truth.poses3d, seed)
    except (InputError, ValueError) as e:
        raise _InputErrorExit(str(e)) from None
    table = Table(title=f"mvm simulate ({preset})")
    table.add_column("measure")
    table.add_column("value", justify="right")
    labels = ", ".join(f"{truth.labels.count(k)} {k}" for k in dict.fromkeys(truth.labels)) or "–"
    for row in (("people", f"{len(truth.poses3d)} ({labels})"), ("frames", str(len(scene.cameras))),
                ("2D poses", str(len(scene.poses))), ("false positives", str(int((truth.person < 0).sum()))),
                ("merged poses", str(int((truth.merged_with >= 0).sum()))),
                ("scene", str(scene_dir)), ("ground truth", str(truth_path))) + (
                    (("rendered frames", f"{scene_dir}/frames"),) if render else ()):
        table.add_row(*row)
    out.print(table)


@click.command("bench")
@click.option("--quick", is_flag=True, help="Two tiny clips and short sweeps (seconds, for CI).")
@click.option("-o", "--out", "out_dir", type=click.Path(file_okay=False), default="benchmarks/results",
              show_default=True, help="Folder for paper_tables.md, clips.csv, sweeps.csv, matching_time.png.")
@click.option("--refine/--no-refine", default=False, show_default=True, help="Run the pose-prior refinement.")
@click.option("--trajectories", type=click.Path(file_okay=False, exists=True), default=None,
              help="Folder of real camera paths (*.txt) used by some clips.")
def bench_cmd(quick, out_dir, refine, trajectories):
    """Reproduce the paper's Tables 1-2 on simulated clips with ground truth, plus sweeps."""
    from mvm.core.config import Config
    from mvm.eval.bench import run_bench
    from mvm.eval.bench_files import write_bench_report

    paths = sorted(str(p) for p in Path(trajectories).glob("*.txt")) if trajectories else []
    t = time.perf_counter()
    try:
        result = run_bench(quick=quick, config=Config(refine=refine), trajectories=paths)
    except InputError as e:
        raise _InputErrorExit(str(e)) from None
    seconds = time.perf_counter() - t
    command = "mvm bench" + (" --quick" if quick else "") + (" --refine" if refine else "")
    path = write_bench_report(result, out_dir, command, seconds)
    table = Table(title=f"mvm bench: Table 1 ({len({r['clip'] for r in result.rows})} clips, {seconds:.0f} s)")
    for column in ("method", "E_R px", "|G_k|", "F1", "MPJPE mm", "matching s"):
        table.add_column(column, justify="left" if column == "method" else "right")
    for row in result.table1 + result.table1_short[:1]:
        table.add_row(row["method"], f"{row['E_R_px']:.1f}", f"{row['G_k']:.1f}", f"{row['f1']:.3f}",
                      f"{row['mpjpe_mm']:.1f}", f"{row['matching_s']:.3f}")
    out.print(table)
    out.print(f"tables: {path}")
