"""The ``mvm`` command: one subcommand per stage, each a thin call of a library function.

Every command module is imported here explicitly (a broken import fails loudly); each keeps
its heavy imports (numpy, scipy, torch, cv2, pycolmap, the pipeline) inside its body, so that
``mvm --help`` and ``mvm --version`` stay fast. Bad input ends in one line on stderr naming the
file, the field and the problem, and exit status 2 (:class:`mvm.cli.common.Group`).
"""
from __future__ import annotations

import logging

import click

from mvm import __version__
from mvm.cli import batch, evaluate, net, report, rig, scene, sim, video
from mvm.cli.common import Group, LogHandler


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="mvm")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
def main(verbose: int) -> None:
    """mvm: multi-person 3D human poses from many views of a static scene."""
    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(verbose, 2)]
    logging.basicConfig(level=level, format="%(message)s", handlers=[LogHandler()])


for command in (scene.reconstruct, sim.demo_cmd, sim.simulate_cmd, sim.bench_cmd, video.run_cmd, video.frames_cmd,
                video.sfm_cmd, video.detect_cmd, rig.rig, net.export_cmd, net.train_cmd, net.predict_cmd, evaluate.evaluate,
                report.report_cmd, report.overlay_cmd, batch.batch_cmd, batch.status_cmd):
    main.add_command(command)


def run() -> None:
    """The ``mvm`` entry point."""
    main(standalone_mode=True)


if __name__ == "__main__":
    run()
