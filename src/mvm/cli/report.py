"""``mvm report`` and ``mvm overlay``: see a reconstruction (thin calls of :mod:`mvm.report`)."""
from __future__ import annotations

from pathlib import Path

import click

from mvm.cli.common import Number, OutputPath, command, output_name_options, resolve_output_name


@command("report")
@click.argument("scene", type=click.Path(file_okay=False))
@click.option("-o", "--out", type=OutputPath((".html", ".htm"), folder=False, product="an .html page"), default=None,
              help="The page to write [default: SCENE/<output-name>/report.html].")
@output_name_options
@click.option("--frames", default=8, show_default=True, type=click.IntRange(0), help="Frames in the overlay strip.")
@click.option("--open", "open_page", is_flag=True, help="Open the page in the default browser.")
def report_cmd(scene, out, output_name, legacy_output, frames, open_page):
    """Write SCENE/<output-name>/report.html: metrics, 3D view, overlays and plots in one offline page."""
    from mvm.report import write_report

    output = resolve_output_name(output_name, legacy_output, "--output")
    path = write_report(Path(scene), output=output, frames=frames, path=out)
    click.echo(f"report: {path} ({path.stat().st_size / 1e6:.2f} MB)")
    if open_page:
        import webbrowser

        webbrowser.open(path.resolve().as_uri())


@command("overlay")
@click.argument("scene", type=click.Path(file_okay=False))
@click.option("-o", "--out", type=OutputPath((".mp4",), product="a .mp4 video or a folder of images"), default=None,
              help="A .mp4 file, or a folder for one image per frame [default: SCENE/<output-name>/overlay/].")
@output_name_options
@click.option("--every", "step", default=1, show_default=True, type=click.IntRange(1), help="Draw every n-th frame.")
@click.option("--max-width", default=None, type=click.IntRange(16), help="Downscale wider frames to this width (px).")
@click.option("--fps", default=10.0, show_default=True, type=Number(float, ge=0.1, le=1000),
              help="Frame rate of a video.")
@click.option("--format", "image_format", type=click.Choice([".jpg", ".png"]), default=".jpg", show_default=True,
              help="Image format in a folder.")
def overlay_cmd(scene, out, output_name, legacy_output, step, max_width, fps, image_format):
    """Draw every frame's 2D poses in the colour of their person and the reprojected 3D poses."""
    from mvm.report import write_overlays

    output = resolve_output_name(output_name, legacy_output, "--output")
    summary = write_overlays(Path(scene), out, output=output, step=step, max_width=max_width,
                             fps=fps, image_format=image_format)
    background = "on the frames" if summary.on_frames else "on a neutral background (no frames/ folder)"
    click.echo(f"overlay: {summary.frames} frames drawn {background} -> {summary.path}")
