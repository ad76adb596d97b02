"""Faults during ``mvm batch``: a worker process killed mid-run, and the driver killed mid-run.
After a rerun every clip is done, every output file parses completely, and no (clip, stage) is
committed twice."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_batch import commits, make_root, parse_outputs, states

from mvm.batch import Manifest, batch_status, run_batch

pytestmark = pytest.mark.skipif(not Path("/proc").is_dir(), reason="finding worker processes needs /proc")

CLIPS = 12


def _children(pid: int) -> list[int]:
    """Pool worker processes of ``pid`` (not multiprocessing's resource tracker)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == pid and "spawn_main" in cmdline:
            found.append(int(entry.name))
    return found


def _start(root: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "mvm", "batch", str(root), "--workers", "2",
                             "--stages", "reconstruct,export"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=dict(os.environ, COLUMNS="200"))


def _wait_for_commits(root: Path, proc: subprocess.Popen, n: int, timeout: float = 90.0) -> int:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc.poll() is not None:
            pytest.fail(f"the run ended before the fault could be injected: {proc.communicate()}")
        if (root / ".mvm" / "manifest.sqlite").is_file():
            done = sum(commits(root).values())
            if done >= n:
                return done
        time.sleep(0.02)
    pytest.fail("no progress")


def _check_all_done(root: Path, good) -> None:
    rows = states(root)
    assert len(rows) == 2 * len(good)
    assert all(r["state"] in ("done", "skipped") for r in rows.values()), \
        {k: r["state"] for k, r in rows.items() if r["state"] not in ("done", "skipped")}
    assert all(count == 1 for count in commits(root).values())        # never committed twice
    parse_outputs(root, good)
    assert batch_status(root, verify=True).mismatched == []


@pytest.fixture
def root(tmp_path):
    good = make_root(tmp_path, n=CLIPS, people=(5, 6), frames=(60, 70), broken=False)
    return tmp_path, good


@pytest.mark.slow
def test_killed_worker_is_retried(root):
    root, good = root
    proc = _start(root)
    _wait_for_commits(root, proc, 2)
    workers = _children(proc.pid)
    assert workers, "no pool worker found"
    os.kill(workers[0], signal.SIGKILL)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    manifest = Manifest(root, create=False)
    history = manifest.history()
    manifest.close()
    lost = [h for h in history if h["event"] == "retry"]
    assert lost and all("worker lost" in h["detail"] for h in lost)
    assert not any(h["event"] == "fail" for h in history)
    _check_all_done(root, good)
    again = run_batch(root, stages=("reconstruct", "export"), workers=1)    # the rerun finds nothing to do
    assert again.committed == 0 and again.done == len(good)
    _check_all_done(root, good)


@pytest.mark.slow
def test_killed_driver_then_rerun(root):
    root, good = root
    proc = _start(root)
    _wait_for_commits(root, proc, 3)
    workers = _children(proc.pid)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    end = time.monotonic() + 10                                        # the workers end with their driver
    while any(Path(f"/proc/{pid}").exists() and "spawn_main" in Path(f"/proc/{pid}/cmdline").read_text(errors="replace")
              for pid in workers) and time.monotonic() < end:
        time.sleep(0.1)
    assert not [pid for pid in workers if Path(f"/proc/{pid}").exists()
                and "spawn_main" in Path(f"/proc/{pid}/cmdline").read_text(errors="replace")]
    before = states(root)
    interrupted = [k for k, r in before.items() if r["state"] == "running"]
    assert any(r["state"] == "pending" for r in before.values())       # it was killed mid-run
    committed_before = commits(root)
    rerun = subprocess.run([sys.executable, "-m", "mvm", "batch", str(root), "--workers", "2", "--stages",
                            "reconstruct,export"], capture_output=True, text=True, timeout=120)
    assert rerun.returncode == 0, rerun.stderr
    _check_all_done(root, good)
    after = commits(root)
    assert all(after[k] == 1 for k in committed_before)                # committed work was not redone
    manifest = Manifest(root, create=False)
    recovered = {(h["clip"], h["stage"]) for h in manifest.history("recover")}
    runs = manifest.runs()
    manifest.close()
    assert recovered == set(interrupted)
    assert [r["outcome"] for r in runs] == ["died", "finished"]
    for cid in good:                                                   # no partial file under any name
        for path in (root / cid / "mvm").rglob("*.json"):
            json.loads(path.read_text())


def _open_manifest(root: Path, start, answers) -> None:
    start.wait()
    try:
        Manifest(root, create=True).close()
        answers.put("ok")
    except Exception as e:                                    # noqa: BLE001 - reported to the test
        answers.put(f"{type(e).__name__}: {e}")


def test_runs_that_create_the_manifest_at_once_all_open_it(tmp_path):
    """Four runs creating one manifest at the same moment (SQLite refuses the switch to WAL
    while another connection holds the new file, without waiting): every one opens it."""
    import multiprocessing

    context = multiprocessing.get_context("fork")
    for trial in range(8):
        start, answers = context.Barrier(4), context.Queue()
        runs = [context.Process(target=_open_manifest, args=(tmp_path / str(trial), start, answers))
                for _ in range(4)]
        for run in runs:
            run.start()
        for run in runs:
            run.join(60)
        assert [answers.get(timeout=5) for _ in runs] == ["ok"] * 4


@pytest.mark.slow
def test_two_drivers_share_one_root(root):
    """Two runs started together on the same root split the clips: each (clip, stage) is
    committed once, by one of them."""
    root, good = root
    procs = [_start(root) for _ in range(2)]
    for proc in procs:
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
    _check_all_done(root, good)
    manifest = Manifest(root, create=False)
    by_run = {}
    for h in manifest.history("commit"):
        by_run[h["run"]] = by_run.get(h["run"], 0) + 1
    manifest.close()
    assert sum(by_run.values()) == 2 * len(good)
    assert len(by_run) == 2, by_run                                     # both did some of the work


def test_a_pool_broken_between_polls_is_restarted_when_the_next_stage_is_submitted():
    """A worker that dies between two polls breaks the pool before the next submit: the stage
    that was running on it is reported lost (and so retried), the new stage runs on a new pool."""
    from concurrent.futures import Future
    from concurrent.futures.process import BrokenProcessPool

    from mvm.batch.clips import Clip
    from mvm.batch.engines import LocalEngine
    from mvm.batch.stages import BatchOptions, StageResult

    class BrokenPool:
        def submit(self, *args):
            raise BrokenProcessPool("a child process terminated abruptly")

        def shutdown(self, wait=True, cancel_futures=False):
            pass

    class FreshPool(BrokenPool):
        def submit(self, fn, clip, stage, options, force=False):
            future = Future()
            future.set_result(StageResult(clip.id, stage, ok=True))
            return future

    engine = LocalEngine(1, BatchOptions())
    engine._pool.shutdown()
    running, new = Clip("a", "a", "/a"), Clip("b", "b", "/b")
    engine._running[Future()] = (running, "reconstruct")            # on the worker that died
    engine._pool, engine._new_pool = BrokenPool(), FreshPool
    engine.submit(new, "reconstruct")
    results = engine.poll(timeout=1.0)
    by_clip = {r.clip: r for r in results}
    assert set(by_clip) == {"a", "b"}
    assert not by_clip["a"].ok and by_clip["a"].transient and "worker lost" in by_clip["a"].error
    assert by_clip["b"].ok
    assert isinstance(engine._pool, FreshPool) and not engine._running
