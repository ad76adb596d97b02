"""The rig path imports no scipy: importing scipy.linalg and scipy.special alone cost about
0.4 s, more than refining a whole rig sequence."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import mvm


def test_rig_pipeline_imports_no_scipy():
    code = "import mvm.rig.reconstruct_rig, sys; print([m for m in sys.modules if m.split('.')[0] == 'scipy'])"
    source = str(Path(mvm.__file__).resolve().parents[1])           # the mvm under test
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([source, os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         timeout=120, check=False)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]"
