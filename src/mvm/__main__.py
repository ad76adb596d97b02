"""``python -m mvm``: the command line."""
from mvm.cli import run

run()
