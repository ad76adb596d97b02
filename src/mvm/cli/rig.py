"""``mvm rig``: synchronized camera rigs (every instant a static scene)."""
from __future__ import annotations

import sys
from pathlib import Path

import click

from mvm.cli.common import (
    DETECTOR_OPTIONS,
    Group,
    Number,
    OutputPath,
    config_options,
    fmt,
    parse_sets,
    print_line,
    print_table,
    progress,
    read_config,
    refuse_unused,
    say,
    stage_progress,
    with_options,
)
from mvm.cli.setting_options import setting_option
from mvm.core.config import DEFAULT_FRAME_RATE_HZ
from mvm.errors import InputError
from mvm.io.calibrations import FORMATS as CALIBRATION_FORMATS

#: The rig driver's settings, whose options take their type, bounds and help from it.
RIG = "mvm.rig.options:RigOptions"


def read_rig_options(config_path: str | None, pairs: tuple[str, ...], **flags):
    """The :class:`~mvm.rig.options.RigOptions` of a TOML file (its ``[rig]`` table), ``--rig-set``
    pairs and the command's own options (``--smoothing``, ``--frame-rate``), every setting
    checked before any work; a ``--rig-set`` key that is not a rig setting is refused."""
    from mvm.core.config import Config
    from mvm.rig.options import RigOptions
    from mvm.settings.tables import load_settings

    values = parse_sets(pairs, "--rig-set")
    refuse_unused(values, RigOptions, "--rig-set", other=(Config, "--set"))
    flags = {k: v for k, v in flags.items() if v is not None}
    return load_settings(RigOptions, "rig", config_path, {**values, **flags},
                         {**{k: "--rig-set" for k in values}, **{k: "--" + k.replace("_", "-") for k in flags}})


#: The ``rig`` commands in the order of the user's path from videos to results.
PATH = ("detect", "synchronize", "calibrate", "reconstruct")


class RigGroup(Group):
    """The ``rig`` group lists its commands in the order of the user's path (:data:`PATH`), not
    alphabetically; commands off the path come after, in the order they were added."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        rank = {name: i for i, name in enumerate(PATH)}
        return sorted(self.commands, key=lambda name: rank.get(name, len(PATH)))


@click.group(cls=RigGroup, context_settings={"help_option_names": ["-h", "--help"]})
def rig() -> None:
    """Camera rigs: a video (or 2D poses) per camera -> synchronized, calibrated, tracked 3D poses.

    \b
    The path of a rig folder, each step's output the next one's input:
      mvm rig detect RIG_DIR                           -> RIG_DIR/pose/ (from RIG_DIR/videos/)
      mvm rig synchronize RIG_DIR                      -> RIG_DIR/sync.toml
      mvm rig calibrate RIG_DIR --from-people -o FILE  -> FILE (a full Calib.toml)
        (or --checkerboard / --charuco: from videos of a board in RIG_DIR/calibration/;
         --convert FILE: another system's calibration, converted)
      mvm rig reconstruct RIG_DIR [--calib FILE]       -> RIG_DIR/mvm/
      mvm report RIG_DIR, mvm overlay RIG_DIR          -> RIG_DIR/mvm/report.html, overlay/
    """


@rig.command("synchronize")
@click.argument("rig_dir", type=click.Path(file_okay=False))
@click.option("--calib", type=click.Path(), default=None,
              help="Calibration (default: found in RIG_DIR); without rotations and translations the epipolar "
                   "geometry is estimated from the people.")
@click.option("--max-offset", type=Number(int, ge=1), default=None,
              help="Largest offset searched, in frames (default 60, or what the shortest video allows).")
@click.option("--force", is_flag=True, help="Synchronize even if sync.toml is up to date.")
def synchronize_cmd(rig_dir, calib, max_offset, force):
    """Find each camera's frame offset from the people's motion; write RIG_DIR/sync.toml (frames to
    add to each camera's frame numbers to reach the reference camera's, the first of the calibration).
    An up-to-date sync.toml (same pose files, calibration and options) is kept."""
    import numpy as np

    from mvm.stages import RigJob, run_stage
    from mvm.stages.rig_synchronize import STAGE

    done = run_stage(STAGE, RigJob(Path(rig_dir), calib=calib, max_offset=max_offset), force)
    if done.why is None:
        say(f"kept {STAGE.record(RigJob(Path(rig_dir)))} (up to date; --force to synchronize again): "
            + ", ".join(f"{n} {o:+d}" for n, o in done.result.items()))
        return
    found = done.result
    r = found.result
    print_table(f"{rig_dir}: offsets to the reference camera {found.names[0]} (searched ±{r.lags.max()} frames, "
                + ("calibrated" if found.calibrated else "epipolar geometry from the people") + ")",
                ("camera", "offset (frames)", "triangulation error px", "correlation peak (lag)", "ambiguous"),
                [(n, f"{int(o):+d}", fmt(e) if np.isfinite(e) else "–", f"{p:.2f} ({int(lag):+d})", "yes" if a else "")
                 for n, o, e, p, lag, a in zip(found.names, r.offsets, r.error_px, r.peak, r.peak_lag, r.ambiguous)])
    for n, p, a in zip(found.names, r.peak, r.ambiguous):
        if a:
            say(f"warning: camera {n}: offset ambiguous (correlation peak {p:.2f}); check it, or trim its video")
    say(f"wrote {found.path}")


@rig.command("calibrate")
@click.argument("rig_dir", type=click.Path(file_okay=False))
@click.option("--from-people", "from_people", is_flag=True,
              help="Find every camera's rotation and position from the people's 2D poses (no calibration object).")
@click.option("--checkerboard", is_flag=True,
              help="Intrinsics and poses from videos of a checkerboard in RIG_DIR/calibration/ (docs/rigs.md).")
@click.option("--charuco", is_flag=True, help="The same with a ChArUco board.")
@click.option("--convert", "convert", type=click.Path(), default=None, metavar="FILE",
              help="Convert a calibration made by another system (Qualisys .qca.txt, Vicon .xcp, EasyMocap, "
                   "OpenCap, anipose, FreeMoCap, caliscope, bioCV; docs/rigs.md) for RIG_DIR's cameras.")
@click.option("--format", "convert_format", type=click.Choice(list(CALIBRATION_FORMATS)), default=None,
              help="The format of --convert's file (default: told from its name and content).")
@click.option("--binning", type=Number(float, gt=0), default=None,
              help="Qualisys's binning factor of the videos (default 1; 2 for 540p video of a 1080p sensor).")
@click.option("-o", "--out", "output", type=click.Path(dir_okay=False), required=True,
              help="The Calib.toml to write (use it with mvm rig reconstruct --calib).")
@click.option("--intrinsics", type=click.Path(dir_okay=False), default=None,
              help="Calib.toml with the cameras' intrinsics (from people: default RIG_DIR's calibration; with a "
                   "board: used instead of calibrating them). Rotations and translations may be absent.")
@click.option("--seed", default=None, type=Number(int, ge=0), help="Random seed of the robust estimation "
              "(--from-people; default 0).")
@click.option("--refine-focal", is_flag=True,
              help="Adjust every camera's focal length in the bundle adjustment too (--from-people; for "
                   "focal lengths that may be more than about 1 % off).")
@click.option("--board-size", default=None, metavar="COLSxROWS",
              help="Checkerboard: inner corners (e.g. 7x6, one count even and one odd); ChArUco: squares (e.g. 5x7).")
@click.option("--square-size", type=Number(float, gt=0), default=None, help="Side of the board's squares, in metres.")
@click.option("--marker-size", type=Number(float, gt=0), default=None,
              help="Side of the ChArUco markers, in metres.")
@click.option("--dictionary", default=None, help="ArUco dictionary of the ChArUco board (default DICT_4X4_50).")
@click.option("--fisheye", is_flag=True, help="Calibrate OpenCV's fisheye lens model (wide-angle lenses).")
@click.option("--intrinsics-only", "intrinsics_only", is_flag=True,
              help="Calibrate each camera's intrinsics and lens alone, from the videos or photos of the board in "
                   "RIG_DIR/calibration/intrinsics/ (or calibration/); write them without rotations and translations.")
@click.option("--world-frame", type=Number(int, ge=0), default=None,
              help="The frame of the extrinsics videos whose board is the world (--world board; default: the "
                   "first frame the most cameras see it in).")
@click.option("--world", type=click.Choice(["board", "camera"]), default=None,
              help="World frame of a board calibration: the board (default; where most cameras first see it "
                   "together: origin on its first corner, z out of its face) or the first camera's frame.")
@click.option("--force", is_flag=True, help="Calibrate even if the output is up to date.")
def calibrate_cmd(rig_dir, from_people, checkerboard, charuco, convert, convert_format, binning, output, intrinsics,
                  seed, refine_focal, board_size, square_size, marker_size, dictionary, fisheye, intrinsics_only,
                  world_frame, world, force):
    """Calibrate the cameras from the people or from videos of a board; write a full Calib.toml.

    \b
    --from-people: the extrinsics from the people the rig sees (metres from
      their bone lengths, z up along their bodies, the origin on the floor
      under them; synchronize first, sync.toml is used).
    --checkerboard / --charuco: intrinsics, lenses and extrinsics from videos
      or photos of a board in RIG_DIR/calibration/ (intrinsics/ and
      extrinsics/, Pose2Sim's int_<cam>_img/, or the videos right there);
      with --intrinsics-only, the lenses alone.
    --convert FILE: a calibration made by another system, converted (metres,
      OpenCV's conventions) for RIG_DIR's cameras, matched by name.
    An up-to-date output (same inputs and options) is kept."""
    modes = [m for m, on in (("--from-people", from_people), ("--checkerboard", checkerboard),
                             ("--charuco", charuco), ("--convert", convert is not None)) if on]
    if len(modes) != 1:
        raise InputError(None, "calibrate", "choose one of --from-people, --checkerboard, --charuco, --convert"
                         + (f" (got {' and '.join(modes)})" if modes else ""))
    if convert is None:
        for option, value in (("--format", convert_format), ("--binning", binning)):
            if value is not None:
                raise InputError(None, option, "applies to --convert only")
    else:
        given = [k for k, v in (("--intrinsics", intrinsics), ("--seed", seed),
                                ("--refine-focal", refine_focal or None),
                                ("--board-size", board_size), ("--square-size", square_size),
                                ("--marker-size", marker_size), ("--dictionary", dictionary),
                                ("--fisheye", fisheye or None), ("--intrinsics-only", intrinsics_only or None),
                                ("--world-frame", world_frame), ("--world", world))
                 if v is not None]
        if given:
            raise InputError(None, given[0], "does not apply to --convert")
        return _calibrate_by_conversion(rig_dir, convert, output, convert_format, binning or 1.0, force)
    board_options = {"--board-size": board_size, "--square-size": square_size, "--marker-size": marker_size,
                     "--dictionary": dictionary, "--fisheye": fisheye or None, "--world-frame": world_frame,
                     "--world": world, "--intrinsics-only": intrinsics_only or None}
    if from_people:
        given = [k for k, v in board_options.items() if v is not None]
        if given:
            raise InputError(None, given[0], "applies to --checkerboard and --charuco, not --from-people")
        return _calibrate_from_people(rig_dir, output, intrinsics, seed or 0, refine_focal, force)
    for option, given in (("--seed", seed is not None), ("--refine-focal", refine_focal)):
        if given:
            raise InputError(None, option, "applies to --from-people only")
    if fisheye and intrinsics:
        raise InputError(None, "--fisheye", "the lens model comes from --intrinsics")
    if world_frame is not None and world == "camera":
        raise InputError(None, "--world-frame", "applies to --world board")
    if intrinsics_only:
        given = [k for k, v in (("--intrinsics", intrinsics), ("--world", world), ("--world-frame", world_frame))
                 if v is not None]
        if given:
            raise InputError(None, given[0], "does not apply to --intrinsics-only")
    _calibrate_from_board(rig_dir, output, intrinsics, "charuco" if charuco else "checkerboard", board_size,
                          square_size, marker_size, dictionary, world or "board", fisheye, world_frame,
                          intrinsics_only, force)


def _calibrate(rig_dir, force: bool, method: str, output, progress=None, **settings):
    """The rig's ``calibrate`` stage (:mod:`mvm.stages.rig_calibrate`) run by ``method``: what it
    found, or None (said in one line) when ``output`` is up to date."""
    from mvm.stages import RigJob, run_stage
    from mvm.stages.rig_calibrate import STAGE, Calibration

    calibration = Calibration(method, Path(output), **settings)
    done = run_stage(STAGE, RigJob(Path(rig_dir), calibration=calibration, progress=progress), force)
    if done.why is None:
        say(f"kept {output} (up to date; --force to calibrate again)")
    return done.result


def _calibrate_by_conversion(rig_dir, source, output, fmt, binning, force):
    found = _calibrate(rig_dir, force, "convert", output, source=Path(source), format=fmt, binning=binning)
    if found is None:
        return
    cams = found.calibration.cameras
    print_table(f"{source}: converted from {found.format}"
                + ("" if found.matched else f" (no videos or poses in {rig_dir}: every camera kept)"),
                ("camera", "focal px", "position x, y, z (m)", "image px"),
                [(n, f"{cams.focal[v]:.1f}", ", ".join(f"{c:.3f}" for c in cams.centers[v]),
                  f"{cams.size[v, 0]:g} x {cams.size[v, 1]:g}") for v, n in enumerate(cams.names)])
    if found.left_out:
        say(f"left out (not in the rig): {', '.join(found.left_out)}")
    say(f"wrote {found.path}")


def _calibrate_from_people(rig_dir, output, intrinsics, seed, refine_focal, force):
    found = _calibrate(rig_dir, force, "people", output, intrinsics=Path(intrinsics) if intrinsics else None,
                       seed=seed, refine_focal=refine_focal)
    if found is None:
        return
    cams = found.calibration.cameras
    r = found.result
    frames = "synchronized by sync.toml" if found.sync else "frame numbers as they are"
    focal = ("focal px (change)",) if refine_focal else ()
    print_table(f"{rig_dir}: calibrated from people ({frames})",
                ("camera", "position x, y, z (m)", "± mm", *focal, "residual px", "joints"),
                [(n, ", ".join(f"{v:.3f}" for v in cams.centers[v]),
                  f"{1000 * r.position_sd_m[v]:.0f}" if v else "(reference)",
                  *((f"{cams.K[v, 0, 0]:.1f} ({100 * (r.focal_scale[v] - 1):+.1f} %)",) if refine_focal else ()),
                  fmt(r.residual_px[v]), str(r.observations[v])) for v, n in enumerate(cams.names)])
    say("± mm: each camera position's standard deviation relative to the reference camera, from the bundle "
        "adjustment")
    say(f"wrote {found.path}")


def _calibrate_from_board(rig_dir, output, intrinsics, kind, board_size, square_size, marker_size, dictionary, world,
                          fisheye, world_frame, intrinsics_only=False, force=False):
    from mvm.rig.board_calibration import MIN_COVERAGE
    from mvm.rig.boards import Board, parse_board_size

    for option, value in (("--board-size", board_size), ("--square-size", square_size)) + (
            (("--marker-size", marker_size),) if kind == "charuco" else ()):
        if value is None:
            raise InputError(None, option, f"required with --{kind}")
    if kind == "checkerboard" and (marker_size is not None or dictionary is not None):
        raise InputError(None, "--marker-size" if marker_size is not None else "--dictionary",
                         "applies to --charuco only")
    try:
        cols, rows = parse_board_size(board_size)
    except ValueError as e:
        raise InputError(None, "--board-size", str(e)) from None
    try:
        board = Board(kind, cols, rows, square_size, marker_size, dictionary or "DICT_4X4_50")
    except ValueError as e:
        what, _, problem = str(e).partition(": ")
        raise InputError(None, "--" + what.replace(" ", "-"), problem) from None
    if intrinsics_only:
        return _board_intrinsics(rig_dir, output, board, fisheye, force)
    with stage_progress() as update:
        found = _calibrate(rig_dir, force, kind, output, update, intrinsics=Path(intrinsics) if intrinsics else None,
                           board=board, world=world, fisheye=fisheye, world_frame=world_frame)
    if found is None:
        return
    cams = found.calibration.cameras
    r = found.rig
    lenses = found.intrinsics
    print_table(f"{rig_dir}: calibrated with a {board.describe()}; world: {found.calibration.metadata['world']}",
                ("camera", "focal px", "position x, y, z (m)", "intrinsics RMS px", "image covered", "residual px",
                 "views"),
                [(n, f"{cams.K[v, 0, 0]:.1f}", ", ".join(f"{c:.3f}" for c in cams.centers[v]),
                  fmt(lenses[v].rms_px) if lenses[v] else "(given)",
                  f"{lenses[v].coverage:.0%}" if lenses[v] else "–", fmt(r.rms_px[v]), str(r.views[v]))
                 for v, n in enumerate(cams.names)])
    for n, lens in zip(cams.names, lenses):
        if lens is not None and lens.coverage < MIN_COVERAGE:
            say(f"warning: camera {n}: the board covered {lens.coverage:.0%} of the image, so its lens and focal "
                "length are uncertain: film the board close up over the whole image (calibration/intrinsics/)")
    say(f"wrote {found.path}")


def _board_intrinsics(rig_dir, output, board, fisheye, force):
    from mvm.rig.board_calibration import MIN_COVERAGE
    from mvm.rig.board_videos import searched

    with stage_progress() as update:
        found = _calibrate(rig_dir, force, "intrinsics", output, update, board=board, fisheye=fisheye)
    if found is None:
        return
    cams = found.calibration.cameras
    print_table(f"{rig_dir}: intrinsics from a {board.describe()} (no rotations nor translations)",
                ("camera", "source", "board found in", "focal px (fx, fy)", "principal point px", "RMS px",
                 "image covered"),
                [(n, found.sources[n].name, f"{s.found} of {searched(s, found.sources[n])}",
                  f"{cams.K[v, 0, 0]:.1f}, {cams.K[v, 1, 1]:.1f}", f"{cams.K[v, 0, 2]:.1f}, {cams.K[v, 1, 2]:.1f}",
                  fmt(lens.rms_px), f"{lens.coverage:.0%}")
                 for v, (n, s, lens) in enumerate(zip(cams.names, found.scans, found.lenses))])
    for n, lens in zip(cams.names, found.lenses):
        if lens.coverage < MIN_COVERAGE:
            say(f"warning: camera {n}: the board covered {lens.coverage:.0%} of the image, so its lens and focal "
                "length are uncertain: film the board close up over the whole image")
    say(f"wrote {found.path} (use it with --intrinsics)")


@rig.command("reconstruct")
@click.argument("rig_dir", type=click.Path(file_okay=False))
@click.option("--calib", type=click.Path(), default=None,
              help="Calibration: Calib.toml, a COLMAP model folder or a Panoptic calibration JSON "
                   "(default: found in RIG_DIR).")
@click.option("--frames", default=None, metavar="START:STOP", help="Frame numbers to use, STOP excluded.")
@click.option("-o", "--out", "output", type=OutputPath(product="a folder (poses3d.jsonl, .trc files, recap.json)"),
              default=None,
              help="Output folder (default RIG_DIR/mvm).")
@setting_option(RIG, "smoothing")
@click.option("--no-complete", "no_complete", is_flag=True,
              help="Leave joints that were not reconstructed empty (null) instead of interpolating "
                   "them along the track and inferring the rest from the pose prior.")
@click.option("--trc-inferred", is_flag=True,
              help="Write inferred joints into the .trc files too (default: observed and interpolated only).")
@setting_option(RIG, "frame_rate",
                help="Rig frame rate in Hz (default: the videos' rate that mvm rig detect recorded, else "
                     f"{DEFAULT_FRAME_RATE_HZ:g}).")
@setting_option(RIG, "workers",
                help="Processes to read, reconstruct and refine with (default: $MVM_WORKERS, else one per core; "
                     "1: this process only).")
@click.option("--rig-set", "rig_sets", multiple=True, metavar="KEY=VALUE",
              help="Override one rig setting (batch_size, max_link_distance_m, max_gap, up, ...).")
@click.option("--force", is_flag=True, help="Reconstruct even if the output set is up to date.")
@config_options
def reconstruct_cmd(rig_dir, calib, frames, output, smoothing, no_complete, trc_inferred, frame_rate, workers,
                    rig_sets, force, config_path, sets, refine):
    """Reconstruct every instant of RIG_DIR, link persons over time, write poses3d.jsonl, one
    .trc per track and recap.json."""
    from mvm.stages import RigJob, run_stage
    from mvm.stages.rig_reconstruct import STAGE

    config = read_config(config_path, sets, "rig", refine=refine, complete=False if no_complete else None)
    options = read_rig_options(config_path, rig_sets, smoothing=smoothing, frame_rate=frame_rate, workers=workers,
                               trc_inferred=True if trc_inferred else None)
    with progress() as bar:
        task = bar.add_task("instants", total=None)
        job = RigJob(Path(rig_dir), config=config, options=options, calib=calib, frames=frames, output=output,
                     progress=lambda _, done, total: bar.update(task, completed=done, total=total))
        done = run_stage(STAGE, job, force)
    why, recap_dict, outputs = done.why, done.result.recap, done.result.outputs
    print_line("output set: " + ("kept (up to date)" if why is None else f"made: {why}"))
    r = recap_dict
    flags = r["joint_flags"]
    names = list(r["excluded_per_camera"])
    filled = f" ({r['persons_filled_whole']} filled where a track missed them)" if r.get("persons_filled_whole") else ""
    print_rig_recap(f"{rig_dir}: {r['instants']} instants, {r['persons']} persons{filled}, {r['tracks']} tracks "
                    f"({r['tracks_resumed']} resumed after a loss), {r['instants_per_s']} instants/s; joints "
                    + ", ".join(f"{k} {v:.1%}" for k, v in flags.items() if v), r)
    worst = max(names, key=lambda n: r["excluded_overall_per_camera"][n] or 0.0, default=None)
    if worst is not None and (r["excluded_overall_per_camera"][worst] or 0) > 0.3:
        say(f"hint: camera {worst} is excluded {r['excluded_overall_per_camera'][worst]:.0%} of the time: "
            "check its calibration, or raise ransac_threshold (--set ransac_threshold=...)")
    if r.get("frame_rate"):
        say(f"frame rate: {r['frame_rate']['hz']:g} Hz ("
            + {"videos": "the videos', recorded by mvm rig detect", "setting": "given",
               "default": "the default; no video recorded one"}.get(r["frame_rate"]["source"], "") + ")")
    if r.get("sync_offsets"):
        say("synchronized by sync.toml (frame numbers are the reference camera's): "
            + ", ".join(f"{n} {o:+d}" for n, o in r["sync_offsets"].items()))
    say(f"{'wrote' if why is not None else 'kept'} {outputs['poses3d']}, {len(outputs['tracks'])} .trc file(s), "
        f"{outputs['recap']}")


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


@rig.command("detect")
@click.argument("rig_dir", type=click.Path(file_okay=False))
@with_options(DETECTOR_OPTIONS)    # not --import nor --appearance: a rig's own detections go in its pose folder
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="TOML settings file: its [detect] table (mvm config prints one); the options given here win.")
@click.option("--force", is_flag=True,
              help="Detect every video again, even where its pose file is up to date; replace pose files mvm did "
                   "not make.")
def detect_cmd(rig_dir, detector, model, person_model, mode, device, batch_size, checkpoint, input_size, config_path,
               force):
    """Detect the 2D poses of every video of RIG_DIR/videos (<camera>.mp4, ...) into
    RIG_DIR/pose/<camera>.json, with the detectors of mvm detect; each video's frame rate and
    frame count are recorded there (mvm rig reconstruct takes its frame rate from them)."""
    from mvm.cli.common import rate_column, refused, stage_progress
    from mvm.cli.video import read_detect_options
    from mvm.stages import RigJob, run_stage
    from mvm.stages.rig_detect import STAGE

    with refused(ValueError):
        options = read_detect_options(config_path, detector, model, person_model, mode, device, batch_size, checkpoint,
                                      None, None, input_size)
    with refused(ValueError), stage_progress(rate_column()) as update:
        found = run_stage(STAGE, RigJob(Path(rig_dir), options, checkpoint, progress=update), force).result
    print_table(f"{rig_dir}: 2D poses of the videos ({options.detector})",
                ("camera", "video", "frames", "frame rate Hz", "2D poses", "pose file"),
                [(c.camera, c.video.file if c.video else "–", str(c.video.frames) if c.video else "–",
                  fmt(c.video.frame_rate, 3) if c.video else "–", str(c.poses),
                  "kept (up to date)" if c.why is None else f"made: {c.why}") for c in found])
    say(f"pose files: {', '.join(str(c.path) for c in found)}")
