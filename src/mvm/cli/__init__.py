"""The `mvm` command line: one subcommand per library function (:mod:`mvm.cli.main`)."""
from mvm.cli.main import main, run

__all__ = ["main", "run"]
