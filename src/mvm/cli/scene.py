"""``mvm reconstruct``: the 3D poses of scene directories (:func:`mvm.scenes.reconstruct_dirs`)."""
from __future__ import annotations

import click

from mvm.cli.common import (
    Number,
    command,
    config_options,
    fmt,
    print_table,
    read_config,
)
from mvm.cli.failures import report_failures, run_outcomes
from mvm.io.layout import DEFAULT_OUTPUT


@command("reconstruct")
@click.argument("scenes", nargs=-1, required=True, type=click.Path())
@config_options
@click.option("--output-name", "output", default=DEFAULT_OUTPUT, show_default=True, metavar="NAME",
              help="Name of the output folder inside each scene directory.")
@click.option("--workers", type=Number(int, ge=1), default=None,
              help="Processes to reconstruct the scenes with (default: $MVM_WORKERS, else one per core; "
                   "1: this process only).")
def reconstruct(scenes, config_path, sets, refine, output, workers):
    """Reconstruct the 3D poses of one or more scene directories.

    Each SCENE holds sparse/ (a COLMAP model) and poses2d.json (COCO keypoints); the result is
    written to SCENE/<output-name>/poses3d.json. A scene that fails, for whatever reason, is reported
    in one line and the others are still done; the exit status is 2 if any scene failed. The
    scenes are shared by --workers processes.
    """
    from mvm.scenes import reconstruct_dirs

    config = read_config(config_path, sets, refine=refine)
    outcomes = reconstruct_dirs(scenes, config, output, workers=workers)
    rows, failed = run_outcomes(len(scenes), outcomes, "reconstructing")
    if rows:
        recap(rows)
    report_failures(failed, len(scenes))


#: Columns of the recap, one row per scene reconstructed.
RECAP_COLUMNS = ("scene", "persons", "matched", "unmatched", "E_R px", "outliers", "|G_k|", "time s")


def recap(rows) -> None:
    """One row per scene reconstructed (:func:`mvm.cli.common.print_table`)."""
    print_table("mvm reconstruct", RECAP_COLUMNS,
                [(str(scene), str(r.metrics["persons"]), str(r.metrics["matched_poses"]),
                  str(r.metrics["unmatched_poses"]), fmt(r.metrics["E_R_px"]), fmt(r.metrics["outliers"], 1),
                  fmt(r.metrics["G_k"], 1), fmt(r.timings["read_s"] + r.timings["total_s"])) for scene, r in rows],
                fold_first=True)
