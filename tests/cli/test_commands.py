"""The command set: every subcommand listed, every ``--help`` working, and a light start-up
(``mvm --help`` imports none of the heavy libraries; timings are in benchmarks/cli_startup.py)."""
from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest
from click.testing import CliRunner

from mvm.cli.main import main

#: Every subcommand of ``mvm``; removing one must be a decision, not an import that broke.
COMMANDS = ("batch", "bench", "config", "demo", "detect", "evaluate", "export", "frames", "overlay", "predict",
            "reconstruct", "report", "rig", "run", "sfm", "simulate", "status", "train")
SUBCOMMANDS = {"rig": ("detect", "synchronize", "calibrate", "reconstruct"), "evaluate": ("3dpw", "coco", "cvar")}


def _listed(help_text: str) -> set[str]:
    section = help_text.split("Commands:", 1)[1]
    return {m.group(1) for m in re.finditer(r"^  (\S+)", section, re.M)}


def test_every_subcommand_is_listed():
    result = CliRunner().invoke(main, ["--help"])
    assert result.exit_code == 0, result.output
    assert _listed(result.output) == set(COMMANDS)
    for group, commands in SUBCOMMANDS.items():
        result = CliRunner().invoke(main, [group, "--help"])
        assert _listed(result.output) == set(commands), group


@pytest.mark.parametrize("command", [[c] for c in COMMANDS] + [[g, c] for g, cs in SUBCOMMANDS.items() for c in cs])
def test_every_help_works(command):
    result = CliRunner().invoke(main, [*command, "--help"])
    assert result.exit_code == 0, result.output
    assert result.output.startswith(f"Usage: main {' '.join(command)} ") or result.output.startswith("Usage: ")
    assert "--help" in result.output and "Show this message and exit." in result.output


HEAVY = ("numpy", "scipy", "torch", "cv2", "pycolmap", "rich", "onnxruntime")


@pytest.mark.parametrize("args", [["--version"], ["--help"], ["reconstruct", "--help"],
                                  ["rig", "reconstruct", "--help"]])
def test_start_up_imports_no_heavy_library(args):
    probe = ("import json, sys\nfrom mvm.cli import main\n"
             f"try:\n    main({args!r}, standalone_mode=False)\n"
             "finally:\n    print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in "
             f"{HEAVY!r} or m == 'mvm.core.reconstruct')))\n")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == []


def test_import_mvm_is_light_and_lazy():
    probe = ("import sys, mvm\nlight = 'scipy' not in sys.modules and 'numpy' not in sys.modules\n"
             "config = mvm.Config(tau=0.3)\nprint(light, config.tau, 'scipy' in sys.modules or 'numpy' in sys.modules,"
             " callable(mvm.reconstruct_dir), 'Config' in dir(mvm))")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert proc.stdout.split() == ["True", "0.3", "False", "True", "True"]
    proc = subprocess.run([sys.executable, "-c", "import mvm; mvm.no_such_name"], capture_output=True, text=True)
    assert proc.returncode == 1 and "module 'mvm' has no attribute 'no_such_name'" in proc.stderr


def test_a_broken_command_module_fails_loudly():
    """A command module that does not import ends the program with its ImportError, instead of
    its commands silently missing from ``mvm --help``."""
    probe = "import sys\nsys.modules['mvm.cli.video'] = None\nfrom mvm.cli import main\nmain(['--help'])\n"
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert proc.returncode == 1 and "ModuleNotFoundError" in proc.stderr and "mvm.cli.video" in proc.stderr
    assert "Commands:" not in proc.stdout


def test_a_subcommand_imports_only_its_own_module():
    """``mvm rig reconstruct`` pays for the rig commands only; every name of the lazy table
    leads to the command of that name."""
    from mvm.cli.main import COMMANDS as LAZY

    assert set(LAZY) == set(COMMANDS)
    assert all(main.get_command(None, name).name == name for name in LAZY)
    probe = ("import json, sys\nfrom mvm.cli import main\n"
             "try:\n    main(['rig', 'reconstruct', '--help'], standalone_mode=False)\n"
             "finally:\n    print(json.dumps(sorted(m for m in sys.modules if m.startswith('mvm.cli.'))))\n")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == ["mvm.cli.common", "mvm.cli.main", "mvm.cli.process",
                                                              "mvm.cli.rig", "mvm.cli.setting_options"]


def test_simulate_reaches_the_crowd_preset_and_real_lengths(tmp_path):
    """``mvm simulate --preset crowd`` makes the dense crowd (12 people by default); the
    options reach 30 people and 3,600 frames, and refuse more in one line."""
    from mvm.io.ground_truth import read_ground_truth
    from mvm.io.layout import SceneLayout

    runner = CliRunner()
    scene = tmp_path / "crowd"
    result = runner.invoke(main, ["simulate", str(scene), "--preset", "crowd", "--frames", "20"])
    assert result.exit_code == 0, result.output
    assert len(read_ground_truth(SceneLayout(scene).truth).poses3d) == 12
    for option, value in (("--people", "31"), ("--frames", "3601")):
        refused = runner.invoke(main, ["simulate", str(tmp_path / "x"), option, value])
        assert refused.exit_code == 2 and option in refused.output
    for i, (preset, people, frames) in enumerate((("crowd", "30", "20"), ("clean", "1", "3600"))):
        accepted = runner.invoke(main, ["simulate", str(tmp_path / f"y{i}"), "--preset", preset,
                                        "--people", people, "--frames", frames])
        assert accepted.exit_code == 0, accepted.output
        truth = read_ground_truth(SceneLayout(tmp_path / f"y{i}").truth)
        assert len(truth.poses3d) == int(people)
