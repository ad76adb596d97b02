"""``mvm status`` on manifests that are not what they should be: a foreign table, a corrupt
cell, a moved root, files changed since they were committed."""
from __future__ import annotations

import json
import shutil
import sqlite3

import pytest
from click.testing import CliRunner

from batch.test_batch import make_root
from mvm.batch import batch_status, run_batch
from mvm.batch.manifest import MANIFEST
from mvm.cli.main import main


@pytest.fixture(scope="module")
def done_root(tmp_path_factory):
    """Three simulated clips reconstructed by ``mvm batch`` (the reconstruct stage only)."""
    root = tmp_path_factory.mktemp("status") / "root"
    make_root(root, n=3, people=(2, 2), frames=(12, 12), broken=False)
    summary = run_batch(root, ("reconstruct",), workers=1)
    assert summary.done == 3 and not summary.failed
    return root


@pytest.fixture
def root(done_root, tmp_path):
    copy = tmp_path / "root"
    shutil.copytree(done_root, copy)
    return copy


def _sql(root, *statements):
    db = sqlite3.connect(root / MANIFEST, isolation_level=None)
    for statement in statements:
        db.execute(statement)
    db.close()


def _status(root, *args):
    return CliRunner().invoke(main, ["status", str(root), *args])


CORRUPT = [
    (["UPDATE stages SET stats = 'x' WHERE rowid = 1"],
     "stages[rowid 1].stats: expected a JSON object of counts and numbers, got 'x'"),
    (["UPDATE stages SET stats = '{\"frames\": \"12\"}' WHERE rowid = 1"],
     "stages[rowid 1].stats: expected a JSON object of counts and numbers, got '{\"frames\": \"12\"}'"),
    (["UPDATE stages SET state = 'bogus' WHERE rowid = 2"],
     "stages[rowid 2].state: expected one of pending, running, done, failed, skipped, got 'bogus'"),
    (["UPDATE stages SET stage = 'dance' WHERE rowid = 1"],
     "stages[rowid 1].stage: expected one of frames, sfm, detect, reconstruct, export, got 'dance'"),
    (["UPDATE stages SET seconds = 'abc' WHERE rowid = 3"],
     "stages[rowid 3].seconds: expected a finite number or null, got 'abc'"),
    (["UPDATE clips SET scene = x'00ff' WHERE rowid = 1"], "clips[rowid 1].scene: expected text, got b'\\x00\\xff'"),
    (["UPDATE stages SET clip = 'elsewhere' WHERE rowid = 1"],
     "stages['elsewhere', 'reconstruct'].clip: not in the clips table"),
    (["DROP TABLE history"], "history: no such table: not a manifest of `mvm batch`"),
    (["DROP TABLE stages", "CREATE TABLE stages (clip TEXT, stage TEXT, value REAL)"],
     "stages: not the table of `mvm batch`: no column state, attempts, run, lease_until, started, finished, "
     "seconds, error, checksum, files, worker, stats, detail"),
]


@pytest.mark.parametrize("json_mode", [False, True], ids=["text", "json"])
@pytest.mark.parametrize("statements, line", CORRUPT, ids=[c[1].split(":")[0] + " " + c[0][0][:20] for c in CORRUPT])
def test_a_corrupt_manifest_is_one_line(root, statements, line, json_mode):
    _sql(root, *statements)
    before = (root / MANIFEST).read_bytes()
    result = _status(root, *(["--json"] if json_mode else []))
    assert result.exit_code == 2, result.output
    assert result.stderr == f"mvm: error: {root / MANIFEST}: {line}\n"
    assert (root / MANIFEST).read_bytes() == before                      # status writes nothing


def test_not_a_database_is_one_line(root):
    for name in ("manifest.sqlite-wal", "manifest.sqlite-shm"):
        (root / ".mvm" / name).unlink(missing_ok=True)
    (root / MANIFEST).write_bytes(b"this is not a database, it only has the name of one" * 100)
    result = _status(root)
    assert result.exit_code == 2
    assert result.stderr == f"mvm: error: {root / MANIFEST}: not a readable manifest: file is not a database\n"


def test_verify_exits_alike_in_text_and_json(root):
    assert _status(root, "--verify").exit_code == 0
    assert _status(root, "--verify", "--json").exit_code == 0
    path = root / "seq00" / "clip00" / "mvm" / "poses3d.json"
    path.write_text(path.read_text().replace('"persons"', '"persons" ', 1))
    text = _status(root, "--verify")
    assert text.exit_code == 1 and "checksum mismatch: seq00/clip00: reconstruct" in text.output
    as_json = _status(root, "--verify", "--json")
    assert as_json.exit_code == 1
    assert json.loads(as_json.stdout)["checksum_mismatches"] == [{"clip": "seq00/clip00", "stage": "reconstruct"}]
    path.unlink()                                                        # an unreadable file is a mismatch too
    assert batch_status(root, verify=True).mismatched == [("seq00/clip00", "reconstruct")]


def test_paths_are_stored_relative_to_the_root(root, tmp_path):
    db = sqlite3.connect(root / MANIFEST)
    scenes = [row[0] for row in db.execute("SELECT scene FROM clips ORDER BY id")]
    db.close()
    assert scenes == ["seq00/clip00", "seq00/clip01", "seq00/clip02"]
    moved = tmp_path / "elsewhere" / "moved"
    moved.parent.mkdir()
    shutil.move(root, moved)
    result = _status(moved, "--verify", "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["checksum_mismatches"] == []
    assert batch_status(moved).statistics["clips"] == 3


def test_old_absolute_paths_still_verify_after_a_move(root, tmp_path):
    _sql(root, f"UPDATE clips SET scene = '{root}/' || id")                 # as older versions stored them
    assert _status(root, "--verify").exit_code == 0
    moved = tmp_path / "moved"
    shutil.move(root, moved)
    result = _status(moved, "--verify")
    assert result.exit_code == 0, result.output
    assert "checksum mismatch" not in result.output
    tampered = moved / "seq00" / "clip01" / "mvm" / "poses3d.json"
    tampered.write_text(tampered.read_text() + " ")
    assert batch_status(moved, verify=True).mismatched == [("seq00/clip01", "reconstruct")]


def test_a_manifest_being_created_reads_as_empty(root):
    """The instant a first run has created the database file but not yet its tables."""
    for name in ("manifest.sqlite", "manifest.sqlite-wal", "manifest.sqlite-shm"):
        (root / ".mvm" / name).unlink(missing_ok=True)
    (root / MANIFEST).write_bytes(b"")
    result = _status(root, "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["clips"] == {"total": 3, "done": 0, "failed": 0, "running": 0, "pending": 3}
    assert (root / MANIFEST).read_bytes() == b""
