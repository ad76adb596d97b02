"""fork_map: the same results as a loop, exceptions raised in the caller, a lost worker's chunk redone."""
import os
import pickle
import signal

import numpy as np
import pytest

from mvm.errors import InputError
from mvm.parallel import Forked, available_workers, fork_map, split

PARENT = os.getpid()


def _work(chunk):
    """A chunk's sum of squares, and the process that computed it."""
    return float((np.asarray(chunk, dtype=float) ** 2).sum()), os.getpid()


def test_split_covers_every_item_once_in_order():
    for n in range(12):
        for parts in range(1, 5):
            ranges = split(n, parts)
            assert [i for r in ranges for i in r] == list(range(n))
            assert all(len(r) > 0 for r in ranges) and len(ranges) <= max(parts, 1)
            assert max(map(len, ranges), default=0) - min(map(len, ranges), default=0) <= 1


def test_results_match_a_loop_and_children_do_the_work():
    chunks = [np.arange(k, k + 50) for k in range(0, 200, 50)]
    results = fork_map(_work, chunks, workers=3)
    assert [r[0] for r in results] == [_work(c)[0] for c in chunks]
    pids = [r[1] for r in results]
    assert pids[0] == PARENT and pids[3] == PARENT             # the first chunk, and the one beyond 3 workers
    assert PARENT not in pids[1:3] and pids[1] != pids[2]


def test_one_worker_runs_everything_here(monkeypatch):
    assert {r[1] for r in fork_map(_work, [[1], [2], [3]], workers=1)} == {PARENT}
    monkeypatch.setenv("MVM_WORKERS", "1")
    assert available_workers() == 1
    assert {r[1] for r in fork_map(_work, [[1], [2]])} == {PARENT}


def _fails_in_second(chunk):
    if chunk == "bad":
        raise InputError("scene/poses2d.json", "annotations[3].keypoints", "expected 51 numbers, got 34")
    return chunk


def test_a_childs_input_error_is_raised_here_whole():
    with pytest.raises(InputError) as info:
        fork_map(_fails_in_second, ["good", "bad"], workers=2)
    assert (info.value.path, info.value.field) == ("scene/poses2d.json", "annotations[3].keypoints")
    assert str(info.value) == "scene/poses2d.json: annotations[3].keypoints: expected 51 numbers, got 34"
    assert pickle.loads(pickle.dumps(info.value)).problem == "expected 51 numbers, got 34"


def _killed_in_child(chunk):
    if os.getpid() != PARENT:
        os.kill(os.getpid(), signal.SIGKILL)
    return _work(chunk)


def test_a_killed_child_has_its_chunk_redone_here():
    results = fork_map(_killed_in_child, [[1, 2], [3, 4]], workers=2)
    assert results == [(5.0, PARENT), (25.0, PARENT)]


def _children() -> set[int]:
    """The processes whose parent is this one (Linux /proc)."""
    found = set()
    for stat in os.listdir("/proc"):
        try:
            with open(f"/proc/{stat}/stat") as f:
                if int(f.read().rsplit(")", 1)[1].split()[1]) == os.getpid():
                    found.add(int(stat))
        except (OSError, ValueError, IndexError):
            continue
    return found


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux /proc to list child processes")
def test_no_child_outlives_the_call():
    before = _children()
    results = fork_map(_work, [[1], [2], [3]], workers=3)
    assert len({pid for _, pid in results}) == 3
    assert _children() <= before


def _logs(chunk):
    import logging
    import warnings

    logging.getLogger("mvm.test").warning("chunk %s done", chunk)
    if chunk == 2:
        warnings.warn("second chunk warns", stacklevel=1)
    return chunk


def test_a_childs_log_records_are_handled_here(caplog):
    with caplog.at_level("WARNING"):
        assert fork_map(_logs, [1, 2], workers=2) == [1, 2]
    messages = [r.getMessage() for r in caplog.records]
    assert messages[:2] == ["chunk 1 done", "chunk 2 done"]
    assert any("second chunk warns" in m for m in messages[2:])


def test_no_process_to_be_had_runs_the_chunk_here(monkeypatch):
    def no_fork():
        raise OSError(11, "Resource temporarily unavailable")

    monkeypatch.setattr(os, "fork", no_fork)
    assert fork_map(_work, [[1], [2]], workers=2) == [(1.0, PARENT), (4.0, PARENT)]


def test_without_fork_every_chunk_runs_here(monkeypatch):
    """Where the system has no fork (Windows), asking for workers runs everything here."""
    monkeypatch.delattr(os, "fork")
    assert fork_map(_work, [[1], [2]], workers=2) == [(1.0, PARENT), (4.0, PARENT)]
    handle = Forked(_work, [3])
    assert handle.result() == (9.0, PARENT)
    handle.stop()
