"""Options of settings take their type, bounds, help and shown default from the settings
dataclass's declaration: what the dataclass refuses, the option refuses in one line; its help is
the field's comment; a value not given leaves the settings file's or the default."""
from __future__ import annotations

import click
from click.testing import CliRunner

from mvm.cli.common import Command
from mvm.cli.setting_options import setting_option
from mvm.rig.options import RigOptions

RIG = "mvm.rig.options:RigOptions"


@click.command(cls=Command)
@setting_option(RIG, "smoothing")
@setting_option(RIG, "workers")
@setting_option(RIG, "frame_rate", "--rate")
def _cmd(smoothing, workers, frame_rate):
    click.echo(f"{smoothing!r} {workers!r} {frame_rate!r}")


def test_values_within_the_declaration_reach_the_command():
    result = CliRunner().invoke(_cmd, ["--smoothing", "savgol", "--workers", "3", "--rate", "25"])
    assert result.exit_code == 0, result.output
    assert result.output.strip() == "'savgol' 3 25.0"
    assert CliRunner().invoke(_cmd, []).output.strip() == "None None None"     # the file's, else the default


def test_values_the_declaration_refuses_are_refused_in_one_line():
    for args, problem in ((["--workers", "-1"], "--workers: must be >= 0, got -1"),
                          (["--workers", "2000"], "--workers: must be <= 1024, got 2000"),
                          (["--rate", "0"], "--rate: must be > 0, got 0.0"),
                          (["--workers", "two"], "--workers: expected int, got 'two'")):
        result = CliRunner().invoke(_cmd, args)
        assert result.exit_code == 2 and problem in result.output, (args, result.output)
    result = CliRunner().invoke(_cmd, ["--smoothing", "gaussian"])
    assert result.exit_code == 2 and "savgol" in result.output


def test_help_is_the_fields_comment_with_its_default():
    text = " ".join(CliRunner().invoke(_cmd, ["--help"]).output.split())
    assert "Temporal smoothing of each track" in text
    assert f"(default: {RigOptions().smoothing})" in text
    assert "[none|butterworth|savgol]" in text


def test_the_video_and_batch_options_are_their_settings_declarations():
    """``mvm run`` and ``mvm batch`` refuse what the frame, SfM and detection settings refuse,
    with the field's bound, and show the field's default: written once, in the dataclasses."""
    import dataclasses

    from mvm.cli import main
    from mvm.video.detect import DetectOptions
    from mvm.video.frames import FrameOptions
    from mvm.video.sfm import SfmOptions

    bound = {f.name: f.metadata["bounds"] for cls in (FrameOptions, SfmOptions, DetectOptions)
             for f in dataclasses.fields(cls) if "bounds" in f.metadata}
    assert (bound["width"].ge, bound["blur_ratio"].le, bound["batch_size"].le) == (16, 1, 4096)
    for command in (["run", "clip.mp4", "-o", "scene"], ["batch", "root"]):
        for args, problem in ((["--width", "8"], "--width: must be >= 16, got 8"),
                              (["--rate", "0"], "--rate: must be > 0, got 0.0"),
                              (["--focal", "-1"], "--focal: must be > 0, got -1.0")):
            result = CliRunner().invoke(main, [*command, *args])
            assert result.exit_code == 2 and problem in result.output, (command, args, result.output)
    for args, problem in ((["--blur-ratio", "1.5"], "--blur-ratio: must be <= 1, got 1.5"),
                          (["--batch-size", "5000"], "--batch-size: must be <= 4096, got 5000"),
                          (["--max-features", "10"], "--max-features: must be >= 64, got 10")):
        result = CliRunner().invoke(main, ["run", "clip.mp4", "-o", "scene", *args])
        assert result.exit_code == 2 and problem in result.output, (args, result.output)
    text = " ".join(CliRunner().invoke(main, ["run", "--help"]).output.split())
    for shown in (f"(fraction, default: {FrameOptions().blur_ratio})", f"(default: {DetectOptions().mode})",
                  f"(features, default: {SfmOptions().max_features})",
                  f"(frames, default: {DetectOptions().batch_size})", "the original size (px)."):
        assert shown in text


def test_a_bound_the_command_narrows_is_the_commands_and_shown():
    """``mvm simulate --people`` keeps its own 1-30 (SimConfig allows 1000); the help shows that
    range beside the field's comment, unit and default."""
    from mvm.cli import main
    from mvm.sim.simulate import SimConfig

    result = CliRunner().invoke(main, ["simulate", "scene", "--people", "31"])
    assert result.exit_code == 2 and "--people: must be <= 30, got 31" in result.output
    text = " ".join(CliRunner().invoke(main, ["simulate", "--help"]).output.split())
    assert f"(people, 1-30, default: {SimConfig().people})" in text
    assert f"(deg, 5-180, default: {SimConfig().arc_deg})" in text
    assert f"(default: {SimConfig().seed})" in text
