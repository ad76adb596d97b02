"""mvm writes only where it owns: an output is never an input, never inside one, never holds one;
an existing folder is replaced only when mvm made it (its marker lists everything in it); the
leftover cleanup removes only marked temporaries; one writer per output at a time."""
from __future__ import annotations

import json
import multiprocessing
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from mvm.io.files import OutputError
from mvm.io.outputs import (
    OUTPUT_MARKER,
    TEMPORARY_MARKER,
    atomic_replace_dir,
    check_output_location,
    check_replaceable,
    leftovers,
    lock_path,
    make_temporary_dir,
    output_lock,
)

from helpers import dead_pid

posix_only = pytest.mark.skipif(sys.platform == "win32", reason="flock and SIGKILL are POSIX")
SRC = str(Path(__file__).resolve().parents[2] / "src")


def _user_folder(path: Path) -> Path:
    (path / "data").mkdir(parents=True)
    (path / "thesis.tex").write_text("chapter 1")
    (path / "data" / "x.csv").write_text("1,2")
    return path


def _snapshot(path: Path) -> dict:
    return {p.relative_to(path).as_posix(): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------------------- location

def test_an_output_that_is_holds_or_lies_inside_an_input_is_refused(tmp_path):
    scene = tmp_path / "scene"
    (scene / "frames").mkdir(parents=True)
    (scene / "poses2d.json").write_text("{}")
    inputs = [scene / "frames", scene / "poses2d.json"]
    cases = {scene / "frames": "is an input of this run",
             scene: "contains the input",
             tmp_path: "contains the input",
             scene / "frames" / "sub": "lies inside the input folder",
             scene / "poses2d.json": "is an input of this run"}
    for output, problem in cases.items():
        with pytest.raises(OutputError, match=problem) as info:
            check_output_location(output, inputs)
        assert "\n" not in str(info.value) and str(info.value).startswith(f"{output}: ")
    assert check_output_location(scene / "mvm" / "overlay", inputs) == scene / "mvm" / "overlay"
    assert check_output_location(tmp_path / "elsewhere", inputs) == tmp_path / "elsewhere"


def test_links_and_relative_names_do_not_hide_an_input(tmp_path, monkeypatch):
    frames = tmp_path / "scene" / "frames"
    frames.mkdir(parents=True)
    (tmp_path / "alias").symlink_to(frames)
    with pytest.raises(OutputError, match="is an input"):
        check_output_location(tmp_path / "alias", [frames])
    with pytest.raises(OutputError, match="lies inside the input folder"):
        check_output_location(tmp_path / "alias" / "x", [frames])
    monkeypatch.chdir(tmp_path / "scene")
    with pytest.raises(OutputError, match="is an input"):
        check_output_location("frames/../frames", [frames])
    with pytest.raises(OutputError, match="contains the input"):
        check_output_location(".", [frames])


# ------------------------------------------------------------------------------ ownership

def test_a_users_folder_is_never_replaced(tmp_path):
    user = _user_folder(tmp_path / "mine")
    before = _snapshot(user)
    with pytest.raises(OutputError, match="mvm did not make") as info:
        atomic_replace_dir(lambda d: (d / "a.txt").write_text("x"), user)
    assert str(info.value).startswith(f"{user}: ") and "\n" not in str(info.value)
    assert _snapshot(user) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]          # no temporary, no lock left
    with pytest.raises(OutputError, match="mvm did not make"):
        check_output_location(user, [])
    check_output_location(user, [], replaced=False)                        # files added to it: allowed


def test_an_empty_folder_and_mvms_own_output_are_replaced(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    atomic_replace_dir(lambda d: (d / "a.txt").write_text("1"), out)
    assert json.loads((out / OUTPUT_MARKER).read_text()) == ["a.txt"]
    atomic_replace_dir(lambda d: (d / "b.txt").write_text("2"), out)
    assert sorted(p.name for p in out.iterdir()) == [OUTPUT_MARKER, "b.txt"]
    # a file a user put into mvm's output is not replaced with it
    (out / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="holds 'notes.txt', which mvm did not write there"):
        atomic_replace_dir(lambda d: (d / "c.txt").write_text("3"), out)
    assert (out / "notes.txt").read_text() == "mine" and (out / "b.txt").read_text() == "2"


@pytest.mark.parametrize("marker", ["", "not json", "{}", "[1, 2]", "link"])
def test_a_forged_or_broken_marker_does_not_make_a_folder_mvms(tmp_path, marker):
    user = _user_folder(tmp_path / "mine")
    if marker == "link":
        (tmp_path / "list.json").write_text('["thesis.tex", "data"]')
        (user / OUTPUT_MARKER).symlink_to(tmp_path / "list.json")
    else:
        (user / OUTPUT_MARKER).write_text(marker)
    with pytest.raises(OutputError, match="mvm did not make"):
        check_replaceable(user)


def test_replace_unmarked_is_for_the_scenes_own_folders(tmp_path):
    sparse = tmp_path / "sparse"
    sparse.mkdir()
    (sparse / "cameras.txt").write_text("old")
    atomic_replace_dir(lambda d: (d / "cameras.txt").write_text("new"), sparse, replace_unmarked=True)
    assert (sparse / "cameras.txt").read_text() == "new" and (sparse / OUTPUT_MARKER).is_file()


# ------------------------------------------------------------------------------- leftovers

def test_only_marked_temporaries_are_removed_as_leftovers(tmp_path):
    out = tmp_path / "out"
    killed = make_temporary_dir(out)
    (killed / "half.json").write_text("{")
    assert killed.name.startswith(".out.mvm-tmp-") and (killed / TEMPORARY_MARKER).is_file()
    keep = {}
    for name in (".out.backup", ".out.old", ".out.mvm-tmp-unmarked", ".out.mvm-tmp-linked", ".out.keep"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "notes.txt").write_text(name)
        keep[name] = name
    (tmp_path / ".out.mvm-tmp-linked" / TEMPORARY_MARKER).symlink_to(killed / TEMPORARY_MARKER)
    (tmp_path / ".out.mvm-tmp-file").write_text("a file, not a folder")
    assert leftovers(out) == [killed]
    atomic_replace_dir(lambda d: (d / "a.txt").write_text("x"), out)
    assert not killed.exists()
    for name in keep:
        assert (tmp_path / name / "notes.txt").read_text() == name
    assert (tmp_path / ".out.mvm-tmp-file").is_file()
    assert not list(out.glob(TEMPORARY_MARKER))


_KILLED_WRITER = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, sys.argv[1])
    from pathlib import Path
    from mvm.io.outputs import atomic_replace_dir

    def build(d):
        (d / "part.txt").write_text("half")
        Path(sys.argv[3]).write_text("started")
        time.sleep(60)

    atomic_replace_dir(build, Path(sys.argv[2]))
""")


def _wait_for(path: Path, seconds: float = 30.0) -> None:
    deadline = time.monotonic() + seconds
    while not path.exists():
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.02)


@posix_only
def test_a_killed_writer_leaves_the_previous_set_and_a_leftover_the_next_run_removes(tmp_path):
    out = tmp_path / "out"
    atomic_replace_dir(lambda d: (d / "a.txt").write_text("previous"), out)
    started = tmp_path / "started"
    process = subprocess.Popen([sys.executable, "-c", _KILLED_WRITER, SRC, str(out), str(started)])
    try:
        _wait_for(started)
        process.send_signal(signal.SIGKILL)
        process.wait(30)
    finally:
        process.kill()
    assert (out / "a.txt").read_text() == "previous"
    assert len(leftovers(out)) == 1 and lock_path(out).exists()            # the dead run's lock file
    atomic_replace_dir(lambda d: (d / "a.txt").write_text("next"), out, lock_timeout_s=1)   # a dead lock: no wait
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "started"]
    assert (out / "a.txt").read_text() == "next"


# ------------------------------------------------------------------------------------ lock

def _hold(path: str, seconds: float, ready) -> None:
    with output_lock(path):
        ready.set()
        time.sleep(seconds)


@posix_only
def test_a_second_writer_waits_a_bounded_time_then_is_refused_in_one_line(tmp_path):
    out = tmp_path / "out"
    context = multiprocessing.get_context("fork")
    ready = context.Event()
    holder = context.Process(target=_hold, args=(str(out), 20.0, ready))
    holder.start()
    try:
        assert ready.wait(30)
        t0 = time.monotonic()
        with pytest.raises(OutputError) as info:
            atomic_replace_dir(lambda d: (d / "a.txt").write_text("x"), out, lock_timeout_s=0.3)
        assert 0.3 <= time.monotonic() - t0 < 10
        assert str(info.value) == (f"{out}: another mvm run is writing {out} (waited 0.3 s): "
                                   "try again when it has finished")
        assert not out.exists() and leftovers(out) == []
    finally:
        holder.kill()
        holder.join(30)
    atomic_replace_dir(lambda d: (d / "a.txt").write_text("x"), out, lock_timeout_s=1)   # released by its death
    assert not lock_path(out).exists()


def _write_many(path: str, tag: int, results) -> None:
    try:
        atomic_replace_dir(lambda d: [(d / f"{tag}-{i}.txt").write_text(str(tag)) for i in range(20)],
                           Path(path), lock_timeout_s=30)
        results.put((tag, "ok"))
    except OutputError as e:
        results.put((tag, str(e)))


@posix_only
def test_concurrent_writers_take_turns_and_leave_one_complete_set(tmp_path):
    out = tmp_path / "out"
    context = multiprocessing.get_context("fork")
    results = context.Queue()
    writers = [context.Process(target=_write_many, args=(str(out), tag, results)) for tag in range(6)]
    for w in writers:
        w.start()
    for w in writers:
        w.join(60)
        assert w.exitcode == 0
    outcomes = dict(results.get(timeout=5) for _ in writers)
    assert set(outcomes.values()) == {"ok"}
    names = sorted(p.name for p in out.iterdir() if p.name != OUTPUT_MARKER)
    tags = {n.split("-")[0] for n in names}
    assert len(tags) == 1 and len(names) == 20                              # one writer's complete set
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_stale_temporary_files_are_only_mvms(tmp_path):
    """The one cleaner of temporaries removes a killed writer's files, by the process number in
    their names: not a live writer's, not a folder, not a name without a process, not a user's."""
    from mvm.io.files import atomic_output, sweep_dead_temporaries

    with pytest.raises(RuntimeError), atomic_output(tmp_path / "poses3d.json") as tmp:
        assert tmp.name.startswith(".poses3d.json.mvm-tmp-") and tmp.name.endswith(".tmp")
        raise RuntimeError("killed")                             # the writer removes its own file
    gone, folder = dead_pid(), tmp_path / "scene"              # a folder this process has not swept yet
    folder.mkdir()
    (folder / f".poses3d.json.mvm-tmp-{gone}-x1y2.tmp").write_text("{")         # what a killed writer leaves
    kept = [".poses3d.json.mine.tmp", f".poses3d.json.mvm-tmp-{gone}-dir.tmp", ".poses3d.json.mvm-tmp-x1y2.tmp",
            f".poses3d.json.mvm-tmp-{os.getpid()}-live.tmp"]
    (folder / kept[1]).mkdir()
    for name in (kept[0], *kept[2:]):
        (folder / name).write_text("kept")
    assert sweep_dead_temporaries(folder) == 1
    assert sorted(p.name for p in folder.iterdir()) == sorted(kept)
    assert list(tmp_path.iterdir()) == [folder]


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="a zombie is told by /proc (Linux)")
def test_a_killed_writer_not_yet_reaped_counts_as_dead(tmp_path):
    """A worker killed while writing is a zombie until its parent reaps it; its temporary is
    swept all the same (the parent redoing its work must not leave it)."""
    import signal
    import time

    from mvm.io.files import sweep_dead_temporaries

    pid = os.fork()
    if pid == 0:                                                                  # the worker
        time.sleep(60)
        os._exit(0)
    try:
        os.kill(pid, signal.SIGKILL)
        for _ in range(100):                                                     # dead, not reaped
            with open(f"/proc/{pid}/stat") as f:
                if f.read().rpartition(")")[2].split()[0] == "Z":
                    break
            time.sleep(0.01)
        (tmp_path / f".poses3d.json.mvm-tmp-{pid}-x1y2.tmp").write_text("{")
        assert sweep_dead_temporaries(tmp_path) == 1 and not list(tmp_path.iterdir())
    finally:
        os.waitpid(pid, 0)
