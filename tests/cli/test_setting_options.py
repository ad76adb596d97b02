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
