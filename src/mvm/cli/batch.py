"""``mvm batch`` and ``mvm status``: a whole data set on a local process pool or Ray,
resumable, with a manifest of every clip and stage (:mod:`mvm.batch`)."""
from __future__ import annotations

import sys

import click

from mvm.cli.common import (
    REFINE_OPTION,
    SET_OPTION,
    command,
    err,
    fmt,
    measure_table,
    out,
    print_line,
    print_table,
    progress,
    read_config,
    say,
)
from mvm.cli.setting_options import FRAMES, SFM, setting_option


def _f(value) -> str:
    return fmt(value, 1, thousands=True)


def read_batch_options(config_path: str | None, sets: tuple[str, ...], checkpoint=None, detector=None,
                       model=None, max_frames=None, rate=None, width=None, focal_px=None, refine=None,
                       every_frame=None):
    """The :class:`~mvm.batch.BatchOptions` of a settings file (its ``[reconstruct]``,
    ``[frames]``, ``[sfm]``, ``[detect]`` and ``[batch]`` tables), ``--set`` pairs and the
    command's own options (an option left at None keeps the file's value)."""
    from mvm.batch import BatchOptions
    from mvm.settings.tables import load_settings
    from mvm.video.detect import DetectOptions
    from mvm.video.frames import FrameOptions
    from mvm.video.sfm import SfmOptions

    def table(cls, name, **flags):
        flags = {k: v for k, v in flags.items() if v is not None}
        options = {"focal_px": "--focal", "select": "--every-frame"}
        return load_settings(cls, name, config_path, flags,
                             {k: options.get(k, "--" + k.replace("_", "-")) for k in flags})

    return table(BatchOptions, "batch", checkpoint=checkpoint).replace(
        config=read_config(config_path, sets, refine=refine),
        frames=table(FrameOptions, "frames", max_frames=max_frames, rate=rate, width=width,
                     select="all" if every_frame else None),
        sfm=table(SfmOptions, "sfm", focal_px=focal_px),
        detect=table(DetectOptions, "detect", detector=detector, model=model))


@command("batch")
@click.argument("root", type=click.Path(file_okay=False))
@click.option("--stages", default=None, metavar="LIST",
              help="Comma-separated stages to run: frames,sfm,detect,reconstruct,export (default: all).")
@click.option("--engine", type=click.Choice(["local", "ray"]), default="local", show_default=True,
              help="A local process pool, or Ray (a local instance or the cluster at --address).")
@click.option("--address", default=None, help="Ray cluster to use, e.g. ray://head:10001 or auto.")
@click.option("--workers", type=click.IntRange(1), default=None,
              help="Parallel stages (default: the cores of this machine, or the Ray cluster's CPUs).")
@click.option("--retries", type=click.IntRange(0), default=2, show_default=True,
              help="Further attempts of a stage after a transient failure (a lost worker, an OS error).")
@click.option("--checkpoint", type=click.Path(dir_okay=False), default=None,
              help="The pose network for detect (default: each clip's imported detections).")
@click.option("--detector", type=click.Choice(["rtmo", "rtmpose", "yolo-pose"]), default=None,
              help="detect: run this 2D pose detector on every clip's frames (default: --checkpoint, or "
                   "each clip's imported detections).")
@click.option("--model", type=click.Path(dir_okay=False), default=None,
              help="detect: the detector's ONNX model (as mvm detect --model; yolo-pose: required).")
@setting_option(FRAMES, "max_frames")
@setting_option(FRAMES, "rate")
@setting_option(FRAMES, "width")
@click.option("--every-frame", is_flag=True, default=None,
              help="Keep every sampled frame (all, or those at --rate) instead of selecting them by camera motion.")
@setting_option(SFM, "focal_px", "--focal")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="TOML settings file: its [reconstruct], [frames], [sfm], [detect] and [batch] tables "
                   "(mvm config prints one).")
@SET_OPTION
@REFINE_OPTION
@click.option("--force", is_flag=True, help="Redo every stage of every clip, even those up to date.")
def batch_cmd(root, stages, engine, address, workers, retries, checkpoint, detector, model, max_frames, rate, width,
              every_frame, focal_px, config_path, sets, refine, force):
    """Run every clip of ROOT (videos and scene directories) through the pipeline.

    Progress and results are recorded in ROOT/.mvm/manifest.sqlite: a rerun does only what is
    not done or out of date (its inputs or settings changed: redone with every stage after it,
    and said why), a failed clip is recorded with its error while the others go on, and the merged
    training set of all exported clips is written to ROOT/.mvm/training/annotations.json.
    Exit status 2 when a clip failed.
    """
    from rich.progress import TextColumn

    from mvm.batch import parse_stages, run_batch

    chosen = parse_stages(stages)
    options = read_batch_options(config_path, sets, checkpoint=checkpoint, detector=detector, model=model,
                                 max_frames=max_frames, rate=rate, width=width, focal_px=focal_px, refine=refine,
                                 every_frame=every_frame)
    try:
        with progress(TextColumn("{task.fields[info]}")) as bar:
            task = bar.add_task("clips", total=None, info="")

            def update(p):
                bar.update(task, total=p.clips, completed=p.done + p.failed,
                           info=f"{p.done} done, {p.failed} failed, {p.running} running, {p.per_second:.2f} clips/s")

            summary = run_batch(root, chosen, engine, workers, address, retries, options, update, force)
    except KeyboardInterrupt:
        err().print(f"interrupted: finished stages are recorded; `mvm batch {root}` continues", style="yellow")
        sys.exit(130)
    rows = [("clips", str(summary.clips)), ("done", str(summary.done)), ("failed", str(len(summary.failed))),
            ("held by another run", str(summary.elsewhere)),
            ("stages committed (retried)", f"{summary.committed} ({summary.retried})"),
            ("stale claims recovered", str(summary.recovered)),
            ("wall time (s)", f"{summary.seconds:.1f}"), ("clips per second", f"{summary.clips_per_second:.3f}")]
    rows += [(f"worker seconds: {k}", f"{v:.1f}") for k, v in summary.stage_seconds.items() if v > 0]
    if summary.training_set:
        rows.append(("training set", str(summary.training_set)))
    measure_table(f"mvm batch: {root} (run {summary.run}, {summary.engine}, {summary.workers} workers)", rows)
    for clip, stage, why in summary.redone[:20]:
        print_line(f"redone: {clip}: {stage}: {why}")
    if len(summary.redone) > 20:
        err().print(f"… and {len(summary.redone) - 20} more stages redone")
    for clip, stage, error in summary.failed[:20]:
        print_line(f"failed: {clip}: {stage}: {error}")
    if len(summary.failed) > 20:
        err().print(f"… and {len(summary.failed) - 20} more (mvm status {root})")
    if summary.failed:
        sys.exit(2)


@command("status")
@click.argument("root", type=click.Path(file_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print the status as one JSON document.")
@click.option("--verify", is_flag=True, help="Hash every committed stage's files again and compare.")
def status_cmd(root, as_json, verify):
    """What is done, failed and pending in ROOT, and the data set's statistics."""
    from mvm.batch import batch_status

    status = batch_status(root, verify=verify)
    if as_json:
        import json

        click.echo(json.dumps(status.to_json(), indent=1))
        sys.exit(1 if status.mismatched else 0)
    c = status.clips
    states = ("done", "skipped", "failed", "running", "pending")
    print_table(f"mvm status: {root} — {c['total']} clips: {c['done']} done, {c['failed']} failed, "
                f"{c['running']} running, {c['pending']} pending ({status.runs} runs)",
                ("stage", *states, "worker s"),
                [(stage, *(str(counts[s]) for s in states), _f(status.seconds.get(stage)))
                 for stage, counts in status.stages.items()])
    s = status.statistics
    print_table("data set", ("statistic", "value"),
                [(label, _f(s[key])) for label, key in (
                    ("sequences", "sequences"), ("clips", "clips"), ("frames", "frames"),
                    ("unmatched 2D poses", "unmatched_poses2d"), ("matched 2D poses", "matched_poses2d"),
                    ("generated 3D poses", "poses3d"), ("avg. clips per sequence", "clips_per_sequence"),
                    ("avg. frames per clip", "frames_per_clip"),
                    ("avg. 2D joints per triangulation", "joints2d_per_triangulation"))])
    for clip, stage, error in status.failed[:20]:
        print_line(f"failed: {clip}: {stage}: {error}", out())
    for clip, stage, why in status.stale[:20]:
        print_line(f"out of date: {clip}: {stage}: {why} (mvm batch {root} redoes it)", out())
    if len(status.stale) > 20:
        print_line(f"… and {len(status.stale) - 20} more stages out of date", out())
    for clip, stage, why in [v for v in status.views if v[2] is not None][:20]:
        print_line(f"out of date: {clip}: {stage}: {why} (mvm {stage} {root}/{clip} redoes it)", out())
    if status.views:
        say(f"pages and overlays: {sum(why is None for *_, why in status.views)} of {len(status.views)} up to date")
    if status.training_set:
        say(f"training set: {status.training_set}")
    for clip, stage in status.mismatched:
        print_line(f"checksum mismatch: {clip}: {stage}", out(), style="red")
    if status.mismatched:
        sys.exit(1)
