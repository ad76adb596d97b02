"""``mvm reconstruct``: the 3D poses of scene directories (:func:`mvm.scenes.reconstruct_dirs`)."""
from __future__ import annotations

import click

from mvm.cli.common import (
    command,
    config_options,
    fmt,
    out,
    print_line,
    read_config,
    report_failures,
    run_outcomes,
    text_table,
)


@command("reconstruct")
@click.argument("scenes", nargs=-1, required=True, type=click.Path())
@config_options
@click.option("-o", "--output", default="mvm", show_default=True,
              help="Name of the output folder inside each scene directory.")
def reconstruct(scenes, config_path, sets, refine, output):
    """Reconstruct the 3D poses of one or more scene directories.

    Each SCENE holds sparse/ (a COLMAP model) and poses2d.json (COCO keypoints); the result is
    written to SCENE/<output>/poses3d.json. A scene that fails, for whatever reason, is reported
    in one line and the others are still done; the exit status is 2 if any scene failed.
    """
    from mvm.scenes import reconstruct_dirs

    config = read_config(config_path, sets, refine=refine)
    rows, failed = run_outcomes(len(scenes), reconstruct_dirs(scenes, config, output), "reconstructing")
    if rows:
        columns = ("scene", "persons", "matched", "unmatched", "E_R px", "outliers", "|G_k|", "time s")
        cells = [(str(scene), str(r.metrics["persons"]), str(r.metrics["matched_poses"]),
                  str(r.metrics["unmatched_poses"]), fmt(r.metrics["E_R_px"]), fmt(r.metrics["outliers"], 1),
                  fmt(r.metrics["G_k"], 1), fmt(r.timings["read_s"] + r.timings["total_s"])) for scene, r in rows]
        print_line(text_table("mvm reconstruct", columns, cells), out())
    report_failures(failed, len(scenes))
