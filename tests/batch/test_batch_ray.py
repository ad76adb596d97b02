"""``mvm batch --engine ray`` on a local Ray instance: ~20 simulated clips, some broken on
purpose; every good clip done, every broken one recorded with its error, and the outputs equal
those of the local engine."""
from __future__ import annotations

import json
import shutil

import pytest
from test_batch import BROKEN, make_root, states, truth_error_mm

from mvm.batch import run_batch

ray = pytest.importorskip("ray", reason="ray is not installed (the 'ray' extra)")


@pytest.fixture(scope="module")
def local_ray():
    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
    except Exception as e:  # noqa: BLE001 - e.g. /dev/shm too small, no free port
        pytest.skip(f"Ray cannot start on this machine: {str(e).splitlines()[0] if str(e) else type(e).__name__}")
    yield
    ray.shutdown()


def _persons(root, cid):
    doc = json.loads((root / cid / "mvm" / "poses3d.json").read_text())
    return [(p["keypoints3d"], p["members"]) for p in doc["persons"]]


@pytest.mark.slow
def test_ray_engine_equals_local_engine(tmp_path, local_ray):
    good = make_root(tmp_path / "ray", n=19, people=(2, 3), frames=(10, 14))
    shutil.copytree(tmp_path / "ray", tmp_path / "local")
    on_ray = run_batch(tmp_path / "ray", engine="ray", workers=2)
    on_pool = run_batch(tmp_path / "local", engine="local", workers=2)
    assert on_ray.clips == 20 and on_ray.done == len(good) == 16
    assert {c: s for c, s, _ in on_ray.failed} == {c: s for c, s, _ in on_pool.failed}
    assert set(c for c, _, _ in on_ray.failed) == set(BROKEN)
    ray_rows, pool_rows = states(tmp_path / "ray"), states(tmp_path / "local")
    assert {k: r["state"] for k, r in ray_rows.items()} == {k: r["state"] for k, r in pool_rows.items()}
    for (cid, stage), row in ray_rows.items():
        if row["state"] == "failed":
            # the same error, up to the root's path
            assert row["error"].replace(str(tmp_path / "ray"), "") == \
                pool_rows[cid, stage]["error"].replace(str(tmp_path / "local"), "")
    for cid in good:
        assert _persons(tmp_path / "ray", cid) == _persons(tmp_path / "local", cid)
        # the supervision has no timings: byte for byte the same, so the same checksum
        assert ray_rows[cid, "export"]["checksum"] == pool_rows[cid, "export"]["checksum"]
        found, true, mpjpe = truth_error_mm(tmp_path / "ray", cid)
        assert found == true and mpjpe < 40.0
    a = json.loads((tmp_path / "ray" / ".mvm" / "training" / "annotations.json").read_text())
    b = json.loads((tmp_path / "local" / ".mvm" / "training" / "annotations.json").read_text())
    assert a["annotations"] == b["annotations"] and len(a["images"]) == len(b["images"]) > 0


@pytest.mark.slow
def test_ray_command_starts_its_own_instance(tmp_path):
    """The command line starts (and stops) a local Ray instance of --workers CPUs itself."""
    import os
    import subprocess
    import sys

    make_root(tmp_path, n=3, broken=False)
    env = dict(os.environ, COLUMNS="200")
    run = subprocess.run([sys.executable, "-m", "mvm", "batch", str(tmp_path), "--engine", "ray", "--workers", "1",
                          "--stages", "reconstruct"], capture_output=True, text=True, timeout=180, env=env)
    if run.returncode != 0 and "cannot start or reach Ray" in run.stderr:
        pytest.skip(run.stderr.strip().splitlines()[-1])
    assert run.returncode == 0, run.stderr
    from mvm.batch import Manifest

    manifest = Manifest(tmp_path, create=False)
    runs = manifest.runs()
    manifest.close()
    assert [(r["engine"], r["workers"], r["outcome"]) for r in runs] == [("ray", 1, "finished")]
    rows = states(tmp_path)
    assert all(r["state"] == "done" for r in rows.values()) and len(rows) == 3
    assert len({r["worker"] for r in rows.values()}) == 1                # one Ray worker process did all three
    assert all(int(r["worker"].split(":")[1]) != os.getpid() for r in rows.values())
