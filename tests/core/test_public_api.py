"""The public API: every documented name resolves, and ``import mvm`` stays cheap."""
from __future__ import annotations

import subprocess
import sys

import mvm


def test_every_public_name_resolves():
    for name in mvm.__all__:
        assert getattr(mvm, name) is not None, name
    assert mvm.reconstruct_dir.__module__ == "mvm.scenes"
    assert mvm.reconstruct.__module__ == "mvm.core.reconstruct"
    assert mvm.reconstruct_many.__module__ == "mvm.core.reconstruct"
    assert mvm.reconstruct_dirs.__module__ == "mvm.scenes"


def test_import_mvm_loads_no_heavy_module():
    code = ("import sys, mvm; heavy = [m for m in ('numpy', 'scipy', 'threadpoolctl') if m in sys.modules]; "
            "print(','.join(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
