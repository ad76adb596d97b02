"""The ``mvm`` command: one subcommand per stage, each a thin call of a library function.

Bad input ends in one line on stderr naming the file, the field and the problem, and exit
status 2.
"""
from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

import click
from rich.console import Console
from rich.logging import RichHandler
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from mvm import __version__
from mvm.core.config import Config, load_config
from mvm.errors import InputError

console = Console(stderr=True)
out = Console()


class InputErrorExit(click.ClickException):
    exit_code = 2

    def show(self, file=None):
        click.echo(f"mvm: error: {self.message}", err=True)


def _overrides(pairs: tuple[str, ...]) -> dict:
    values = {}
    for pair in pairs:
        if "=" not in pair:
            raise InputError("--set", pair, "expected KEY=VALUE")
        key, value = pair.split("=", 1)
        values[key.strip()] = value.strip()
    return values


def _config(config_path: str | None, sets: tuple[str, ...], **flags) -> Config:
    config = load_config(config_path, _overrides(sets))
    changes = {k: v for k, v in flags.items() if v is not None}
    return config.replace(**changes) if changes else config


def _fmt(value, digits=2) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return "–" if value != value else f"{value:.{digits}f}"
    return str(value)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="mvm")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
def main(verbose: int) -> None:
    """mvm: multi-person 3D human poses from many views of a static scene."""
    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(verbose, 2)]
    logging.basicConfig(level=level, format="%(message)s",
                        handlers=[RichHandler(console=console, show_time=False, show_path=False)])


config_options = [
    click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
                 help="TOML file of settings (see the README's configuration reference)."),
    click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
                 help="Override one setting, e.g. --set tau=0.25 (repeatable)."),
    click.option("--refine/--no-refine", default=None, help="Run the pose-prior refinement."),
]


def with_config(f):
    for option in reversed(config_options):
        f = option(f)
    return f


@main.command()
@click.argument("scenes", nargs=-1, required=True, type=click.Path())
@with_config
@click.option("-o", "--output", default="mvm", show_default=True,
              help="Name of the output folder inside each scene directory.")
def reconstruct(scenes, config_path, sets, refine, output):
    """Reconstruct the 3D poses of one or more scene directories.

    Each SCENE holds sparse/ (a COLMAP model) and poses2d.json (COCO keypoints); the result is
    written to SCENE/<output>/poses3d.json. A scene with bad input is reported and skipped;
    the exit status is 2 if any scene failed.
    """
    from mvm.scenes import reconstruct_dir

    try:
        config = _config(config_path, sets, refine=refine)
    except InputError as e:
        raise InputErrorExit(str(e)) from None
    rows, failed = [], []
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console, transient=True) as progress:
        task = progress.add_task("reconstructing", total=len(scenes))
        for scene in scenes:
            progress.update(task, description=f"reconstructing {Path(scene).name}")
            try:
                result = reconstruct_dir(scene, config, output)
            except InputError as e:
                failed.append(scene)
                progress.console.print(f"mvm: error: {e}", markup=False, highlight=False, soft_wrap=True)
            else:
                rows.append((scene, result))
            progress.advance(task)
    if rows:
        table = Table(title="mvm reconstruct")
        for column in ("scene", "persons", "matched", "unmatched", "E_R px", "outliers", "|G_k|", "time s"):
            table.add_column(column, justify="right" if column != "scene" else "left")
        for scene, r in rows:
            m = r.metrics
            table.add_row(str(scene), str(m["persons"]), str(m["matched_poses"]), str(m["unmatched_poses"]),
                          _fmt(m["E_R_px"]), _fmt(m["outliers"], 1), _fmt(m["G_k"], 1),
                          _fmt(r.timings["read_s"] + r.timings["total_s"]))
        out.print(table)
    if failed:
        console.print(f"{len(failed)} of {len(scenes)} scene(s) failed", style="red")
        sys.exit(2)


@main.command()
@click.option("--people", default=6, show_default=True, help="Persons in the scene.")
@click.option("--frames", default=100, show_default=True, help="Frames of the camera tour.")
@click.option("--arc", "arc_deg", default=60.0, show_default=True, help="Total angle of the tour (deg).")
@click.option("--seed", default=0, show_default=True, help="Random seed of the simulation.")
@click.option("-o", "--out", "out_dir", type=click.Path(file_okay=False), default="mvm-demo",
              show_default=True, help="Where to write the simulated scene and its ground truth.")
@with_config
def demo(people, frames, arc_deg, seed, out_dir, config_path, sets, refine):
    """Simulate a mannequin scene, reconstruct it and print accuracy against ground truth."""
    from mvm.eval.demo import run_demo
    from mvm.sim.simulate import SimConfig

    try:
        config = _config(config_path, sets, refine=refine)
        sim = SimConfig(people=people, frames=frames, arc_deg=arc_deg, seed=seed)
        t = time.perf_counter()
        report = run_demo(Path(out_dir), sim, config)
    except (InputError, ValueError) as e:
        raise InputErrorExit(str(e)) from None
    table = Table(title=f"mvm demo: {people} people, {frames} frames, {arc_deg:g}° tour (seed {seed})")
    table.add_column("measure")
    table.add_column("value", justify="right")
    rows = [
        ("persons found / true", f"{report['persons_found']} / {report['persons_true']}"),
        ("2D poses (false positives)", f"{report['poses']} ({report['false_poses']})"),
        ("matching precision (pairwise)", _fmt(report["precision"], 4)),
        ("matching recall (pairwise)", _fmt(report["recall"], 4)),
        ("MPJPE (mm)", _fmt(report["mpjpe_mm"], 1)),
        ("PA-MPJPE (mm)", _fmt(report["pa_mpjpe_mm"], 1)),
        ("E_R (px)", _fmt(report["E_R_px"])),
        ("outliers per 3D pose", _fmt(report["outliers"], 1)),
        ("|G_k| (2D keypoints per joint)", _fmt(report["G_k"], 1)),
        ("time: matching / triangulation / refinement (s)",
         " / ".join(_fmt(report["timings"][k], 3) for k in ("matching_s", "triangulation_s", "refinement_s"))),
        ("time: whole demo (s)", _fmt(time.perf_counter() - t)),
    ]
    for row in rows:
        table.add_row(*row)
    out.print(table)
    out.print(f"scene: {report['scene']}  result: {report['poses3d']}  ground truth: {report['ground_truth']}")


def _register_optional_commands() -> None:
    """Subcommands of optional parts (they import their heavy dependencies lazily)."""
    import importlib

    for module, names in (
        ("mvm.cli.sim", ("simulate_cmd", "bench_cmd")),
        ("mvm.cli.video", ("run_cmd", "frames_cmd", "sfm_cmd", "detect_cmd")),
        ("mvm.cli.rig", ("rig",)),
        ("mvm.cli.net", ("export_cmd", "train_cmd", "predict_cmd")),
        ("mvm.cli.evaluate", ("evaluate",)),
        ("mvm.cli.report", ("report_cmd", "overlay_cmd")),
        ("mvm.cli.batch", ("batch_cmd", "status_cmd")),
    ):
        try:
            mod = importlib.import_module(module)
        except ImportError:
            continue
        for name in names:
            command = getattr(mod, name, None)
            if command is not None:
                main.add_command(command)


_register_optional_commands()


def run() -> None:
    """Entry point that turns any ``InputError`` escaping a command into one line and exit 2."""
    try:
        main(standalone_mode=True)
    except InputError as e:
        click.echo(f"mvm: error: {e}", err=True)
        sys.exit(2)


if __name__ == "__main__":
    run()
