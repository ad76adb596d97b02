"""``mvm report`` and ``mvm overlay``: see a reconstruction (thin calls of :mod:`mvm.report`)."""
from __future__ import annotations

from pathlib import Path

import click

from mvm.cli.common import Number, OutputPath, command, output_name_option, say


@command("report")
@click.argument("scene", type=click.Path(file_okay=False))
@click.option("-o", "--out", type=OutputPath((".html", ".htm"), folder=False, product="an .html page"), default=None,
              help="The page to write [default: SCENE/<output-name>/report.html].")
@output_name_option
@click.option("--frames", default=8, show_default=True, type=click.IntRange(0), help="Frames in the overlay strip.")
@click.option("--calib", type=click.Path(), default=None,
              help="A rig's calibration [default: the one its reconstruction used].")
@click.option("--open", "open_page", is_flag=True, help="Open the page in the default browser.")
@click.option("--force", is_flag=True, help="Write the page even if it is up to date.")
def report_cmd(scene, out, output, frames, calib, open_page, force):
    """Write SCENE/<output-name>/report.html: metrics, 3D view, overlays and plots in one offline page.

    SCENE may be a rig folder reconstructed by mvm rig reconstruct: its page holds the recap, the 3D
    view over the instants, every track's timeline, each camera's reprojection error over time and
    the joint angles of each track. A page up to date (drawn from the same files, with the same
    options) is kept."""
    from mvm.stages import run_stage
    from mvm.stages.view import ViewJob
    from mvm.stages.view_report import STAGE

    job = ViewJob(Path(scene), output, out and Path(out),
                  calib and Path(calib), frames)
    if not job.rig:
        refuse_rig_option(calib, "--calib")
    done = run_stage(STAGE, job, force)
    path = done.result
    if done.why is None:
        say(f"kept {path} (up to date; --force to write it again)")
    click.echo(f"report: {path} ({path.stat().st_size / 1e6:.2f} MB)")
    if open_page:
        import webbrowser

        webbrowser.open(path.resolve().as_uri())


@command("overlay")
@click.argument("scene", type=click.Path(file_okay=False))
@click.option("-o", "--out", type=OutputPath((".mp4",), product="a .mp4 video or a folder of images"), default=None,
              help="A .mp4 file, or a folder for one image per frame [default: SCENE/<output-name>/overlay/].")
@output_name_option
@click.option("--every", "step", default=1, show_default=True, type=click.IntRange(1), help="Draw every n-th frame.")
@click.option("--max-width", default=None, type=click.IntRange(16), help="Downscale wider frames to this width (px).")
@click.option("--fps", default=10.0, show_default=True, type=Number(float, ge=0.1, le=1000),
              help="Frame rate of a video.")
@click.option("--format", "image_format", type=click.Choice([".jpg", ".png"]), default=".jpg", show_default=True,
              help="Image format in a folder.")
@click.option("--calib", type=click.Path(), default=None,
              help="A rig's calibration [default: the one its reconstruction used].")
@click.option("--force", is_flag=True, help="Draw the overlay even if it is up to date.")
def overlay_cmd(scene, out, output, step, max_width, fps, image_format, calib, force):
    """Draw every frame's 2D poses in the colour of their person and the reprojected 3D poses.

    SCENE may be a rig folder reconstructed by mvm rig reconstruct: each camera's video
    (SCENE/videos/<camera>.<ext>) is drawn on, one video per camera in SCENE/<output-name>/overlay/
    (or -o FOLDER), at the video's own frame rate, frame offsets of sync.toml applied. An overlay up
    to date (drawn from the same files, with the same options) is kept."""
    from mvm.stages import run_stage
    from mvm.stages.view import ViewJob
    from mvm.stages.view_overlay import STAGE, target

    job = ViewJob(Path(scene), output, out and Path(out),
                  calib and Path(calib), step=step, max_width=max_width, fps=fps, image_format=image_format)
    if not job.rig:
        refuse_rig_option(calib, "--calib")
    done = run_stage(STAGE, job, force)
    if done.why is None:
        say(f"kept {target(job)} (up to date; --force to draw it again)")
    elif job.rig:
        rig_overlay(scene, done.result)
    else:
        background = "on the frames" if done.result.on_frames else "on a neutral background (no frames/ folder)"
        click.echo(f"overlay: {done.result.frames} frames drawn {background} -> {done.result.path}")


def refuse_rig_option(value, option: str) -> None:
    """Refuse an option only a rig folder takes, given for a scene directory."""
    if value is not None:
        from mvm.errors import InputError

        raise InputError(None, option, "is for a rig folder (reconstructed by mvm rig reconstruct), not a scene")


def rig_overlay(rig_dir, summary) -> None:
    """The recap of ``mvm overlay RIG_DIR``: one video per camera with a video; the others named in one line."""
    for name, (path, count) in summary.videos.items():
        click.echo(f"overlay: {name}: {count} frames drawn -> {path}")
    if summary.skipped:
        say(f"overlay: no video for camera {', '.join(summary.skipped)} (expected {rig_dir}/videos/<camera>.mp4): "
            "skipped")
