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
def report_cmd(scene, out, output, frames, calib, open_page):
    """Write SCENE/<output-name>/report.html: metrics, 3D view, overlays and plots in one offline page.

    SCENE may be a rig folder reconstructed by mvm rig reconstruct: its page holds the recap, the 3D
    view over the instants, every track's timeline, each camera's reprojection error over time and
    the joint angles of each track."""
    from mvm.report import write_report
    from mvm.report.rig_load import is_rig_dir

    if is_rig_dir(scene, output):
        from mvm.report.rig_page import write_rig_report

        path = write_rig_report(Path(scene), output=output, path=out, calib=calib)
    else:
        refuse_rig_option(calib, "--calib")
        path = write_report(Path(scene), output=output, frames=frames, path=out)
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
def overlay_cmd(scene, out, output, step, max_width, fps, image_format, calib):
    """Draw every frame's 2D poses in the colour of their person and the reprojected 3D poses.

    SCENE may be a rig folder reconstructed by mvm rig reconstruct: each camera's video
    (SCENE/videos/<camera>.<ext>) is drawn on, one video per camera in SCENE/<output-name>/overlay/
    (or -o FOLDER), at the video's own frame rate, frame offsets of sync.toml applied."""
    from mvm.report import write_overlays
    from mvm.report.rig_load import is_rig_dir

    if is_rig_dir(scene, output):
        return rig_overlay(scene, out, output, step, max_width, calib)
    refuse_rig_option(calib, "--calib")
    summary = write_overlays(Path(scene), out, output=output, step=step, max_width=max_width,
                             fps=fps, image_format=image_format)
    background = "on the frames" if summary.on_frames else "on a neutral background (no frames/ folder)"
    click.echo(f"overlay: {summary.frames} frames drawn {background} -> {summary.path}")


def refuse_rig_option(value, option: str) -> None:
    """Refuse an option only a rig folder takes, given for a scene directory."""
    if value is not None:
        from mvm.errors import InputError

        raise InputError(None, option, "is for a rig folder (reconstructed by mvm rig reconstruct), not a scene")


def rig_overlay(rig_dir, out, output, step, max_width, calib) -> None:
    """``mvm overlay RIG_DIR``: one video per camera with a video; the others named in one line."""
    from mvm.report.rig_overlay import write_rig_overlays

    summary = write_rig_overlays(Path(rig_dir), out, output=output, calib=calib, step=step, max_width=max_width)
    for name, (path, count) in summary.videos.items():
        click.echo(f"overlay: {name}: {count} frames drawn -> {path}")
    if summary.skipped:
        say(f"overlay: no video for camera {', '.join(summary.skipped)} (expected {rig_dir}/videos/<camera>.mp4): "
            "skipped")
