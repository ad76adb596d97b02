"""``mvm reconstruct``: the 3D poses of scene directories (:func:`mvm.scenes.reconstruct_dirs`)."""
from __future__ import annotations

import click

from mvm.cli.common import Number, command, config_options, fmt, out, read_config, report_failures, run_outcomes


@command("reconstruct")
@click.argument("scenes", nargs=-1, required=True, type=click.Path())
@config_options
@click.option("-o", "--output", default="mvm", show_default=True,
              help="Name of the output folder inside each scene directory.")
@click.option("--workers", type=Number(int, ge=1), default=None,
              help="Processes sharing the scenes (default: $MVM_WORKERS, else the available cores).")
def reconstruct(scenes, config_path, sets, refine, output, workers):
    """Reconstruct the 3D poses of one or more scene directories.

    Each SCENE holds sparse/ (a COLMAP model) and poses2d.json (COCO keypoints); the result is
    written to SCENE/<output>/poses3d.json. A scene that fails, for whatever reason, is reported
    in one line and the others are still done; the exit status is 2 if any scene failed.
    """
    from mvm.scenes import reconstruct_dirs

    config = read_config(config_path, sets, refine=refine)
    rows, failed = run_outcomes(len(scenes), reconstruct_dirs(scenes, config, output, workers=workers), "reconstructing")
    if rows:
        from rich.table import Table

        table = Table(title="mvm reconstruct")
        table.add_column("scene", overflow="fold")                          # a path is never cut
        for column in ("persons", "matched", "unmatched", "E_R px", "outliers", "|G_k|", "time s"):
            table.add_column(column, justify="right")
        for scene, r in rows:
            m = r.metrics
            table.add_row(str(scene), str(m["persons"]), str(m["matched_poses"]), str(m["unmatched_poses"]),
                          fmt(m["E_R_px"]), fmt(m["outliers"], 1), fmt(m["G_k"], 1),
                          fmt(r.timings["read_s"] + r.timings["total_s"]))
        out().print(table)
    report_failures(failed, len(scenes))
