"""``mvm run | frames | sfm | detect``: from a video file to a scene directory and 3D poses.

Each command is a thin call of one library function in :mod:`mvm.video` and prints a recap.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import click

from mvm.cli.common import (
    DETECTOR_OPTIONS,
    REFINE_OPTION,
    SET_OPTION,
    OutputPath,
    command,
    err,
    measure_table,
    rate_column,
    read_config,
    refused,
    say,
    stage_progress,
    with_options,
)
from mvm.cli.common import fmt as _f
from mvm.cli.setting_options import DETECT, FRAMES, SFM, setting_option
from mvm.errors import InputError

#: ``--config`` of the video commands: the tables of their settings.
config_option = click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
                             help="TOML settings file (mvm config prints one); the options given here win.")
frame_options = [
    setting_option(FRAMES, "rate"),
    setting_option(FRAMES, "max_frames"),
    setting_option(FRAMES, "width"),
    setting_option(FRAMES, "blur_ratio"),
    click.option("--every-frame", is_flag=True, default=None,
                 help="Keep every sampled frame (all, or those at --rate) instead of selecting them by camera motion."),
    setting_option(FRAMES, "min_motion"),
    setting_option(FRAMES, "max_gap_s", "--max-gap"),
]
sfm_options = [
    setting_option(SFM, "camera_model", metavar="MODEL"),
    setting_option(SFM, "focal_px", "--focal"),
    click.option("--fix-focal", is_flag=True, help="Keep the known focal length fixed in bundle adjustment."),
    setting_option(SFM, "max_features"),
    click.option("--vocab-tree", type=click.Path(dir_okay=False), default=None,
                 help="COLMAP vocabulary tree: enables loop detection in sequential matching."),
]
detect_options = DETECTOR_OPTIONS + [
    click.option("--import", "source", type=click.Path(), default=None,
                 help="Detections to import: COCO results/dataset JSON, OpenPifPaf or OpenPose directory "
                      "(a COCO results image_id is a frame's file name, or its 1-based position in frames.json)."),
    click.option("--format", "fmt", type=click.Choice(["coco-results", "coco", "openpifpaf", "openpose"]),
                 default=None, help="Format of --import (guessed by default)."),
    setting_option(DETECT, "appearance"),
]


def _table(cls, table: str, config_path, names: dict | None = None, **flags):
    """The settings ``cls`` of ``table`` of the settings file ``config_path`` with the command's
    options ``flags`` over it (one left at None keeps the file's value, or the default); a bad
    value names the option (``names``: the options not spelt as their setting)."""
    from mvm.settings.tables import load_settings

    flags = {k: v for k, v in flags.items() if v is not None}
    return load_settings(cls, table, config_path, flags,
                         {k: (names or {}).get(k, "--" + k.replace("_", "-")) for k in flags})


def _frame_options(config_path, rate, max_frames, width, blur_ratio, every_frame=None, min_motion=None,
                   max_gap_s=None):
    from mvm.video.frames import FrameOptions

    return _table(FrameOptions, "frames", config_path, {"select": "--every-frame", "max_gap_s": "--max-gap"},
                  rate=rate, max_frames=max_frames, width=width, blur_ratio=blur_ratio,
                  select="all" if every_frame else None, min_motion=min_motion, max_gap_s=max_gap_s)


def read_detect_options(config_path, detector, model, person_model, mode, device, batch_size, checkpoint, source,
                        appearance, input_size=None):
    """The detection settings; when no detector is named (option or file), the installed one (rtmo)."""
    from mvm.video.detect import DetectOptions
    from mvm.video.detectors import available_detector

    options = _table(DetectOptions, "detect", config_path, detector=detector, model=model, person_model=person_model,
                     mode=mode, device=device, batch_size=batch_size, appearance=appearance, input_size=input_size)
    detector = options.detector if options.detector != "import" else None
    if input_size is not None and checkpoint is None:
        raise InputError(None, "--input-size", "sizes mvm's network: goes with --checkpoint")
    if source is not None and (detector or checkpoint):
        raise InputError(None, "--import", "imported detections replace the detector: drop --detector/--checkpoint")
    if checkpoint is not None and detector not in (None, "mvm"):
        raise InputError(None, "--checkpoint", f"goes with --detector mvm, not {detector}")
    if detector == "mvm" and checkpoint is None:
        raise InputError(None, "--detector mvm", "give the network's --checkpoint")
    if source is not None:
        detector = "import"
    elif checkpoint is not None:
        detector = "mvm"
    elif detector is None:
        detector = available_detector()
        if detector is None:
            raise InputError(None, "--detector", 'no 2D pose detector is installed: pip install "mvm[detect]" '
                                                 "(RTMO through ONNX Runtime), or give --import or --checkpoint")
    return dataclasses.replace(options, detector=detector)


def _sfm_options(config_path, camera_model, focal_px, fix_focal, max_features, vocab_tree):
    from mvm.video.sfm import SfmOptions

    return _table(SfmOptions, "sfm", config_path, {"focal_px": "--focal", "refine_focal": "--fix-focal"},
                  camera_model=camera_model, focal_px=focal_px, refine_focal=False if fix_focal else None,
                  max_features=max_features, vocab_tree=vocab_tree)


def _say_why(stage: str, why: str | None) -> None:
    """One line on stderr: whether ``stage`` was kept (up to date) or made again, and why."""
    err().print(f"{stage}: " + ("kept (up to date)" if why is None else f"made: {why}"), highlight=False,
                markup=False)


def _sfm_rows(report):
    total = len(report.registered) + len(report.unregistered)
    return [("cameras from", report.source), ("registered frames", f"{len(report.registered)} / {total}"),
            ("reprojection error (px)", _f(report.reprojection_error_px)),
            ("focal length (px)", _f(report.focal_px, 1)),
            ("3D points", str(report.points))]


@command("frames")
@click.argument("video", type=click.Path(dir_okay=False))
@click.option("-o", "--out", "scene", type=OutputPath(product="a scene directory"), required=True,
              help="The scene directory to write (frames/, frames.json).")
@with_options(frame_options)
@config_option
@click.option("--force", is_flag=True, help="Redo even if frames.json is up to date.")
def frames_cmd(video, scene, rate, max_frames, width, blur_ratio, every_frame, min_motion, max_gap_s, config_path,
               force):
    """Decode VIDEO into SCENE/frames and SCENE/frames.json: the sharp frames the camera's motion
    calls for (--every-frame: every sampled one)."""
    from mvm.video.frames import extract_frames

    options = _frame_options(config_path, rate, max_frames, width, blur_ratio, every_frame, min_motion, max_gap_s)
    with refused(ValueError), stage_progress(rate_column()) as update:
        index = extract_frames(video, scene, options, force, lambda d, t: update("frames", d, t))
    _say_why("frames", index.why)
    measure_table("mvm frames", [("frames kept", str(len(index.names))),
                                 ("selection", _selection_text(index.selection)),
                                 ("skipped as blurred", str(len(index.skipped))),
                                 ("size (px)", f"{index.size[0]}×{index.size[1]}"), ("video fps", _f(index.fps, 3))])


def _selection_text(selection: dict) -> str:
    """The rule that kept a scene's frames, in words (``FrameIndex.selection``)."""
    if selection.get("rule") != "motion":
        return "every sampled frame" + (f" ({selection['candidates']})" if "candidates" in selection else "")
    return (f"camera motion ≥ {selection['min_motion']:g} of the diagonal, gap ≤ {selection['max_gap_s']:g} s: "
            f"{selection['kept']} of {selection['candidates']} sampled")


@command("sfm")
@click.argument("scene", type=click.Path(file_okay=False))
@with_options(sfm_options)
@click.option("--cameras", type=click.Path(), default=None,
              help="Use these cameras instead of SfM: a COLMAP model directory or a RealEstate10K/"
                   "MannequinChallenge camera file.")
@config_option
@click.option("--force", is_flag=True, help="Redo even if the model is up to date; replace a model mvm did not make.")
def sfm_cmd(scene, camera_model, focal_px, fix_focal, max_features, vocab_tree, cameras, config_path, force):
    """Estimate the camera of every frame of SCENE (writes SCENE/sparse)."""
    from mvm.video import sfm

    with refused(ValueError), stage_progress() as update:
        if cameras is None:
            report = sfm.run_sfm(scene, _sfm_options(config_path, camera_model, focal_px, fix_focal, max_features,
                                                     vocab_tree), force, update)
        elif Path(cameras).is_dir():
            report = sfm.import_colmap(cameras, scene, force)
        else:
            report = sfm.import_trajectory(cameras, scene, force)
    _say_why("cameras", report.why)
    measure_table("mvm sfm", _sfm_rows(report))
    if report.unregistered:
        err().print(f"not registered (excluded): {', '.join(report.unregistered[:10])}", style="yellow")


@command("detect")
@click.argument("scene", type=click.Path(file_okay=False))
@with_options(detect_options)
@config_option
@click.option("--force", is_flag=True, help="Redo even if poses2d.json is up to date; replace one mvm did not make.")
def detect_cmd(scene, detector, model, person_model, mode, device, batch_size, checkpoint, input_size, source, fmt,
               appearance, config_path, force):
    """2D poses and appearance of every frame of SCENE (writes SCENE/poses2d.json)."""
    from mvm.video.detect import detect_scene

    with refused(ValueError):
        options = read_detect_options(config_path, detector, model, person_model, mode, device, batch_size, checkpoint,
                                      source, appearance, input_size)
    with refused(ValueError), stage_progress(rate_column()) as update:
        d = detect_scene(scene, source, checkpoint, fmt, options, force,
                         lambda done, total: update("detecting", done, total))
    _say_why("2D poses", d.why)
    measure_table("mvm detect", [("source", d.source), ("frames", str(len(d.names))),
                                 ("2D poses", str(len(d.keypoints))),
                                 ("frames skipped (unreadable)", str(len(d.skipped))),
                                 ("appearance",
                                  "none" if d.appearance is None else f"{d.appearance.shape[1]} numbers")])


@command("run")
@click.argument("video", type=click.Path(dir_okay=False))
@click.option("-o", "--out", "scene", type=OutputPath(product="a scene directory"), required=True,
              help="The scene directory to write (frames, cameras, 2D poses, mvm/poses3d.json).")
@with_options(frame_options + sfm_options + detect_options)
@click.option("--cameras", type=click.Path(), default=None,
              help="Use these cameras instead of SfM (COLMAP model directory or camera file).")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="TOML settings file: its [frames], [sfm], [detect] and [reconstruct] tables (mvm config "
                   "prints one); the options given here win.")
@SET_OPTION
@REFINE_OPTION
@click.option("--metric/--no-metric", default=True, show_default=True,
              help="Scale the world to metres from the people's bone lengths.")
@click.option("--force", "force", multiple=True, type=click.Choice(["all", "frames", "sfm", "detect", "reconstruct"]),
              help="Redo this stage and the ones after it (repeatable).")
def run_cmd(video, scene, rate, max_frames, width, blur_ratio, every_frame, min_motion, max_gap_s, camera_model,
            focal_px, fix_focal, max_features, vocab_tree, detector, model, person_model, mode, device, batch_size,
            checkpoint, input_size, source, fmt, appearance, cameras, config_path, sets, refine, metric, force):
    """VIDEO -> frames -> cameras -> 2D poses -> appearance -> 3D poses in SCENE/mvm/poses3d.json."""
    from mvm.stages.run import run_video

    with refused(ValueError):
        options = read_detect_options(config_path, detector, model, person_model, mode, device, batch_size, checkpoint,
                                      source, appearance, input_size)
    with refused(ValueError):
        config = read_config(config_path, sets, refine=refine)
        with stage_progress(rate_column()) as update:
            r = run_video(video, scene, detections=source, checkpoint=checkpoint, detections_format=fmt,
                          cameras=cameras,
                          frame_options=_frame_options(config_path, rate, max_frames, width, blur_ratio,
                                                       every_frame, min_motion, max_gap_s),
                          sfm_options=_sfm_options(config_path, camera_model, focal_px, fix_focal, max_features,
                                                   vocab_tree),
                          detect_options=options, config=config,
                          metric_scale=metric, force="all" if "all" in force else tuple(force), progress=update)
    for stage, why in r.why.items():
        _say_why(stage, why)
    rec = r.reconstruction
    scale = rec.scale.to_json()
    rows = [("frames", str(len(r.frames.names))), ("selection", _selection_text(r.frames.selection))] + \
        _sfm_rows(r.sfm) + [
        ("2D poses", str(len(r.detections.keypoints))), ("persons", str(rec.persons)),
        ("E_R (px)", _f(rec.metrics.get("E_R_px"))),
        ("scale", f"{scale['source']}: {_f(scale['sfm_metres_per_unit'], 4)} m per SfM unit"),
        ("time: frames / sfm / detect / reconstruct (s)", " / ".join(_f(r.seconds[k], 1) for k in
                                                                   ("frames", "sfm", "detect", "reconstruct"))),
    ]
    measure_table(f"mvm run: {scene}", rows)
    say(f"result: {rec.path}")
