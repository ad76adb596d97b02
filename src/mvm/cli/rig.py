"""``mvm rig``: synchronized camera rigs (every instant a static scene)."""
from __future__ import annotations

import dataclasses

import click
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from mvm.cli.main import _config, _fmt, console, out, with_config
from mvm.errors import InputError
from mvm.rig.options import RigOptions


def _bool(value: str) -> bool:
    if value.lower() in ("1", "true", "yes", "on"):
        return True
    if value.lower() in ("0", "false", "no", "off"):
        return False
    raise ValueError(value)


_PARSERS = {"int": int, "float": float, "str": str, "bool": _bool,
            "float | None": lambda v: None if v.lower() in ("none", "auto") else float(v)}


def _options(pairs: tuple[str, ...], **flags) -> RigOptions:
    values = {}
    types = {f.name: f.type for f in dataclasses.fields(RigOptions)}
    for pair in pairs:
        if "=" not in pair:
            raise InputError("--rig-set", pair, "expected KEY=VALUE")
        key, value = (s.strip() for s in pair.split("=", 1))
        if key not in types:
            raise InputError("--rig-set", key, f"unknown setting (known: {', '.join(sorted(types))})")
        try:
            values[key] = _PARSERS[types[key]](value)
        except (ValueError, KeyError):
            raise InputError("--rig-set", key, f"expected {types[key]}, got {value!r}") from None
    values.update({k: v for k, v in flags.items() if v is not None})
    try:
        return RigOptions(**values)
    except ValueError as e:
        raise InputError("--rig-set", None, str(e)) from None


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def rig() -> None:
    """Synchronized camera rigs: Calib.toml + 2D poses per camera -> tracked 3D poses and .trc."""


@rig.command("reconstruct")
@click.argument("rig_dir", type=click.Path(file_okay=False))
@click.option("--calib", type=click.Path(), default=None,
              help="Calibration: Calib.toml, a COLMAP model folder or a Panoptic calibration JSON "
                   "(default: found in RIG_DIR).")
@click.option("--frames", default=None, metavar="START:STOP", help="Frame numbers to use, STOP excluded.")
@click.option("--output", "-o", type=click.Path(file_okay=False), default=None,
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
@click.option("--rig-set", "rig_sets", multiple=True, metavar="KEY=VALUE",
              help="Override one rig setting (batch_size, max_link_distance_m, max_gap, up, ...).")
@with_config
def reconstruct_cmd(rig_dir, calib, frames, output, smoothing, no_complete, trc_inferred, frame_rate, rig_sets,
                    config_path, sets, refine):
    """Reconstruct every instant of RIG_DIR, link persons over time, write poses3d.jsonl, one
    .trc per track and recap.json."""
    from mvm.rig.pipeline import reconstruct_rig

    config = _config(config_path, sets, refine=refine)
    options = _options(rig_sets, smoothing=smoothing, frame_rate=frame_rate,
                       complete=False if no_complete else None, trc_inferred=True if trc_inferred else None)
    with Progress(TextColumn("instants"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console, transient=True) as bar:
        task = bar.add_task("instants", total=None)
        result = reconstruct_rig(rig_dir, config, options, calib, frames, output,
                                 progress=lambda done, total: bar.update(task, completed=done, total=total))
    r = result.recap
    flags = r["joint_flags"]
    table = Table(title=f"{rig_dir}: {r['instants']} instants, {r['persons']} persons, {r['tracks']} tracks "
                        f"({r['tracks_resumed']} resumed after a loss), {r['instants_per_s']} instants/s; joints "
                        + ", ".join(f"{k} {v:.1%}" for k, v in flags.items() if v))
    table.add_column("keypoint")
    table.add_column("error px", justify="right")
    table.add_column("views", justify="right")
    names = list(r["excluded_per_camera"])
    for name in names:
        table.add_column(f"excl. {name}", justify="right")
    for j, kp in enumerate(r["keypoints"]):
        table.add_row(kp, _fmt(r["error_per_keypoint_px"][j]), _fmt(r["views_per_keypoint"][j]),
                      *[_fmt(r["excluded_per_camera"][n][j]) for n in names])
    out.print(table)
    worst = max(names, key=lambda n: r["excluded_overall_per_camera"][n] or 0.0, default=None)
    if worst is not None and (r["excluded_overall_per_camera"][worst] or 0) > 0.3:
        out.print(f"hint: camera {worst} is excluded {r['excluded_overall_per_camera'][worst]:.0%} of the time: "
                  "check its calibration, or raise ransac_threshold_px (--set ransac_threshold_px=...)")
    out.print(f"wrote {result.outputs['poses3d']}, {len(result.outputs['tracks'])} .trc file(s), "
              f"{result.outputs['recap']}")
