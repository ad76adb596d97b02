"""The ``mvm`` command: one subcommand per stage, each a thin call of a library function.

A subcommand's module is imported when that subcommand runs (:data:`COMMANDS`; ``mvm --help``
imports them all, and a test imports every one, so a broken import fails loudly); each keeps
its heavy imports (numpy, torch, cv2, pycolmap, the pipeline) inside its body, so that
``mvm --help`` and ``mvm --version`` stay fast. Bad input ends in one line on stderr naming the
file, the field and the problem, and exit status 2 (:class:`mvm.cli.common.Group`).
"""
from __future__ import annotations

import importlib
import logging

import click

from mvm import __version__
from mvm.cli.common import Group, LogHandler

#: Subcommand -> ``module:object`` under :mod:`mvm.cli`.
COMMANDS = {"reconstruct": "scene:reconstruct", "demo": "sim:demo_cmd", "simulate": "sim:simulate_cmd",
            "bench": "sim:bench_cmd", "run": "video:run_cmd", "frames": "video:frames_cmd", "sfm": "video:sfm_cmd",
            "detect": "video:detect_cmd", "rig": "rig:rig", "export": "net:export_cmd", "train": "net:train_cmd",
            "predict": "net:predict_cmd", "evaluate": "evaluate:evaluate", "report": "report:report_cmd",
            "overlay": "report:overlay_cmd", "batch": "batch:batch_cmd", "status": "batch:status_cmd",
            "config": "config:config_cmd"}


class _Commands(Group):
    """The top-level group: its subcommands come from :data:`COMMANDS`, imported on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in COMMANDS:
            return None
        module, attribute = COMMANDS[name].split(":")
        return getattr(importlib.import_module(f"mvm.cli.{module}"), attribute)


@click.group(cls=_Commands, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="mvm")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
@click.pass_context
def main(ctx: click.Context, verbose: int) -> None:
    """mvm: multi-person 3D human poses from many views of a static scene."""
    from mvm.cli.process import install_signal_handlers, native_output_to_log

    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(verbose, 2)]
    logging.basicConfig(level=level, format="%(message)s", handlers=[LogHandler()])
    install_signal_handlers()
    if not verbose:               # COLMAP's, FFmpeg's and OpenCV's own lines go to the log, not the terminal
        ctx.with_resource(native_output_to_log())


def run() -> None:
    """The ``mvm`` entry point."""
    main(standalone_mode=True)


if __name__ == "__main__":
    run()
