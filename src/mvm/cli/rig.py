"""``mvm rig``: synchronized camera rigs (every instant a static scene)."""
from __future__ import annotations

import sys

import click

from mvm.cli.common import (
    Group,
    OutputPath,
    config_options,
    fmt,
    parse_sets,
    print_table,
    progress,
    read_config,
    refuse_unused,
    say,
)


def read_rig_options(config_path: str | None, pairs: tuple[str, ...], **flags):
    """The :class:`~mvm.rig.options.RigOptions` of a TOML file (its ``[rig]`` table), ``--rig-set``
    pairs and the command's own options (``--smoothing``, ``--frame-rate``), every setting
    checked before any work; a ``--rig-set`` key that is not a rig setting is refused."""
    from mvm.core.config import Config
    from mvm.io.settings_file import load_settings
    from mvm.rig.options import RigOptions

    values = parse_sets(pairs, "--rig-set")
    refuse_unused(values, RigOptions, "--rig-set", other=(Config, "--set"))
    flags = {k: v for k, v in flags.items() if v is not None}
    return load_settings(RigOptions, "rig", config_path, {**values, **flags},
                         {**{k: "--rig-set" for k in values}, **{k: "--" + k.replace("_", "-") for k in flags}})


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"]})
def rig() -> None:
    """Synchronized camera rigs: Calib.toml + 2D poses per camera -> tracked 3D poses and .trc."""


@rig.command("reconstruct")
@click.argument("rig_dir", type=click.Path(file_okay=False))
@click.option("--calib", type=click.Path(), default=None,
              help="Calibration: Calib.toml, a COLMAP model folder or a Panoptic calibration JSON "
                   "(default: found in RIG_DIR).")
@click.option("--frames", default=None, metavar="START:STOP", help="Frame numbers to use, STOP excluded.")
@click.option("--output", "-o", type=OutputPath(product="a folder (poses3d.jsonl, .trc files, recap.json)"),
              default=None,
              help="Output folder (default RIG_DIR/mvm).")
@click.option("--smoothing", type=click.Choice(["none", "butterworth", "savgol"]), default=None,
              help="Temporal smoothing of each track (default butterworth, cut-off 6 Hz or a fifth "
                   "of the frame rate).")
@click.option("--no-complete", "no_complete", is_flag=True,
              help="Leave joints that were not reconstructed empty (null) instead of interpolating "
                   "them along the track and inferring the rest from the pose prior.")
@click.option("--trc-inferred", is_flag=True,
              help="Write inferred joints into the .trc files too (default: observed and interpolated only).")
@click.option("--frame-rate", type=float, default=None, help="Rig frame rate in Hz (default 30).")
@click.option("--workers", type=int, default=None,
              help="Processes to read, reconstruct and refine with (default: $MVM_WORKERS, else one per core; "
                   "1: this process only).")
@click.option("--rig-set", "rig_sets", multiple=True, metavar="KEY=VALUE",
              help="Override one rig setting (batch_size, max_link_distance_m, max_gap, up, ...).")
@config_options
def reconstruct_cmd(rig_dir, calib, frames, output, smoothing, no_complete, trc_inferred, frame_rate, workers,
                    rig_sets, config_path, sets, refine):
    """Reconstruct every instant of RIG_DIR, link persons over time, write poses3d.jsonl, one
    .trc per track and recap.json."""
    from mvm.rig.reconstruct_rig import reconstruct_rig

    config = read_config(config_path, sets, "rig", refine=refine, complete=False if no_complete else None)
    options = read_rig_options(config_path, rig_sets, smoothing=smoothing, frame_rate=frame_rate, workers=workers,
                               trc_inferred=True if trc_inferred else None)
    with progress() as bar:
        task = bar.add_task("instants", total=None)
        result = reconstruct_rig(rig_dir, config, options, calib, frames, output,
                                 progress=lambda done, total: bar.update(task, completed=done, total=total))
    r = result.recap
    flags = r["joint_flags"]
    names = list(r["excluded_per_camera"])
    print_rig_recap(f"{rig_dir}: {r['instants']} instants, {r['persons']} persons, {r['tracks']} tracks "
                    f"({r['tracks_resumed']} resumed after a loss), {r['instants_per_s']} instants/s; joints "
                    + ", ".join(f"{k} {v:.1%}" for k, v in flags.items() if v), r)
    worst = max(names, key=lambda n: r["excluded_overall_per_camera"][n] or 0.0, default=None)
    if worst is not None and (r["excluded_overall_per_camera"][worst] or 0) > 0.3:
        say(f"hint: camera {worst} is excluded {r['excluded_overall_per_camera'][worst]:.0%} of the time: "
            "check its calibration, or raise ransac_threshold_px (--set ransac_threshold_px=...)")
    say(f"wrote {result.outputs['poses3d']}, {len(result.outputs['tracks'])} .trc file(s), "
        f"{result.outputs['recap']}")


#: What ``excl.`` means in the rig recap, said once under it.
EXCLUDED_NOTE = "excl.: share of a camera's keypoints that triangulation excluded as outliers (RANSAC)"


def print_rig_recap(title: str, r: dict) -> None:
    """The recap of a rig reconstruction (``r``: its ``recap.json``): per keypoint the
    reprojection error, the views and, per camera, the share excluded. Where one column per
    camera does not fit the terminal (at 80 columns, more than 3 cameras), the table is split: per
    keypoint the mean and the worst camera's share, then one row per camera. A pipe gets every
    column (tab-separated lines)."""
    from mvm.cli.common import is_terminal, out, table_fits

    names = list(r["excluded_per_camera"])
    per_camera = r["excluded_per_camera"]
    columns = ("keypoint", "error px", "views", *[f"excl. {n}" for n in names])
    rows = [(kp, fmt(r["error_per_keypoint_px"][j]), fmt(r["views_per_keypoint"][j]),
             *[fmt(per_camera[n][j]) for n in names]) for j, kp in enumerate(r["keypoints"])]
    if not is_terminal(sys.stdout) or table_fits(columns, rows, out().width):
        print_table(title, columns, rows, caption=EXCLUDED_NOTE)
        return

    def share(n, j):
        value = per_camera[n][j]
        return -1.0 if value is None else value

    rows = []
    for j, kp in enumerate(r["keypoints"]):
        known = [per_camera[n][j] for n in names if per_camera[n][j] is not None]
        worst = max(names, key=lambda n: share(n, j), default=None)
        rows.append((kp, fmt(r["error_per_keypoint_px"][j]), fmt(r["views_per_keypoint"][j]),
                     fmt(sum(known) / len(known) if known else None),
                     "–" if worst is None or per_camera[worst][j] is None else f"{fmt(per_camera[worst][j])} {worst}"))
    print_table(title, ("keypoint", "error px", "views", "excl. mean", "excl. most (camera)"), rows)
    camera_rows = []
    for n in names:
        j = max(range(len(r["keypoints"])), key=lambda j: share(n, j))
        camera_rows.append((n, fmt(r["excluded_overall_per_camera"][n]),
                            "–" if per_camera[n][j] is None else f"{r['keypoints'][j]} {fmt(per_camera[n][j])}"))
    print_table(None, ("camera", "excl. overall", "excl. most (keypoint)"), camera_rows, caption=EXCLUDED_NOTE)
