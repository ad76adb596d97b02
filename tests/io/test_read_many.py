"""read_many: the reads of many files of one folder refuse what read_bytes refuses, with the same
message, and return the same bytes."""
import os
import sys
import threading

import pytest

from mvm.errors import InputError
from mvm.io.checks import read_bytes, read_many

posix_only = pytest.mark.skipif(sys.platform == "win32", reason="links, FIFOs and devices as on POSIX")


def _outcome(read, path, **kw):
    try:
        return read(path, **kw)
    except InputError as e:
        return str(e)


def _many(path, root=None, limit=None):
    return list(read_many([path], root, limit))[0]


@posix_only
def test_read_many_refuses_what_read_bytes_refuses(tmp_path):
    outside = tmp_path / "secret.json"
    outside.write_text('{"secret": 1}')
    root = tmp_path / "rig"
    cam = root / "pose" / "cam_1"
    cam.mkdir(parents=True)
    (cam / "a.json").write_text('{"people": []}')
    (cam / "in.json").symlink_to(cam / "a.json")               # a link inside the root is read
    (cam / "out.json").symlink_to(outside)
    (cam / "loop.json").symlink_to(cam / "loop.json")
    (cam / "zero.json").symlink_to("/dev/zero")
    (cam / "big.json").write_bytes(b" " * 3000)
    (cam / "folder.json").mkdir()
    os.mkfifo(cam / "fifo.json")
    (root / "linked").symlink_to(tmp_path, target_is_directory=True)     # a folder leading out
    names = ["a.json", "in.json", "out.json", "loop.json", "zero.json", "big.json", "folder.json",
             "fifo.json", "missing.json"]
    paths = [cam / n for n in names] + [root / "linked" / "secret.json"]
    outcomes = []
    worker = threading.Thread(target=lambda: outcomes.extend(
        (_outcome(read_bytes, p, root=root, limit=2048), _outcome(_many, p, root=root, limit=2048)) for p in paths),
        daemon=True)
    worker.start()
    worker.join(timeout=10)
    assert len(outcomes) == len(paths)                                  # nothing blocked on the FIFO
    for path, (one, many) in zip(paths, outcomes):
        assert one == many, path
    got = dict(zip([p.name for p in paths], [one for one, _ in outcomes]))
    assert got["a.json"] == got["in.json"] == b'{"people": []}'
    assert "leads outside" in got["out.json"] and "leads outside" in got["secret.json"]
    assert "FIFO" in got["fifo.json"] and "leads outside" in got["zero.json"]        # /dev/zero is outside too
    assert "limit" in got["big.json"] and "is a directory" in got["folder.json"] and "not found" in got["missing.json"]


def test_read_many_reads_every_file_in_order(tmp_path):
    folders = [tmp_path / "a", tmp_path / "b"]
    paths = []
    for f in folders:
        f.mkdir()
        for i in range(3):
            (f / f"{i}.json").write_text(f"{f.name}{i}")
            paths.append(f / f"{i}.json")
    paths.append(paths[0])                                          # back to a folder already read
    assert list(read_many(paths, root=tmp_path)) == [p.read_bytes() for p in paths]
    assert list(read_many(paths)) == [p.read_bytes() for p in paths]
