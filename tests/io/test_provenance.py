"""The record of an output's inputs: content hashes of files and folders, settings, and the one
phrase that says what changed."""
from __future__ import annotations

import os
from dataclasses import dataclass

import pytest

from mvm.errors import InputError
from mvm.io.provenance import (
    MISSING,
    check_fresh,
    fingerprint,
    read_record,
    record_path,
    stale_reason,
    why_redo,
    write_record,
)


@dataclass(frozen=True)
class Options:
    rate: float | None = None
    width: int = 640


def test_record_path_beside_the_output(tmp_path):
    assert record_path(tmp_path / "poses2d.json") == tmp_path / "poses2d.inputs.json"
    assert record_path(tmp_path / "poses3d.jsonl") == tmp_path / "poses3d.inputs.json"
    (tmp_path / "sparse").mkdir()
    assert record_path(tmp_path / "sparse") == tmp_path / "sparse.inputs.json"


def test_fingerprints_follow_the_content_not_the_time(tmp_path):
    a = tmp_path / "a.json"
    a.write_text("[1, 2]")
    first = fingerprint(a)
    os.utime(a, (0, 0))
    assert fingerprint(a) == first                                   # touched, same bytes
    a.write_text("[1, 3]")
    os.utime(a, (0, 0))
    assert fingerprint(a) != first                                   # same time, other bytes
    assert fingerprint(tmp_path / "nothing") == MISSING


def test_folder_fingerprint_is_its_files_names_and_contents(tmp_path):
    folder = tmp_path / "frames"
    (folder / "sub").mkdir(parents=True)
    (folder / "a.jpg").write_bytes(b"a")
    (folder / "sub" / "b.jpg").write_bytes(b"b")
    first = fingerprint(folder)
    (folder / ".lock").write_bytes(b"x")                              # hidden files do not count
    assert fingerprint(folder) == first
    (folder / "a.jpg").rename(folder / "c.jpg")
    assert fingerprint(folder) != first


def test_a_fifo_is_refused_not_read(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="is a FIFO"):
        fingerprint(fifo)


def test_why_redo_names_what_changed(tmp_path):
    out, source = tmp_path / "out.json", tmp_path / "in.json"
    source.write_text("1")
    inputs = {"in.json": source, "names": ["a", "b"]}
    assert why_redo(out, inputs, Options(), "the test") == "no output yet"
    out.write_text("{}")
    assert why_redo(out, inputs, Options(), "the test").startswith("out.json has no record of its inputs")
    write_record(out, "the test", inputs, Options())
    assert read_record(out)["settings"] == {"rate": None, "width": 640}
    assert why_redo(out, inputs, Options(), "the test") is None
    assert why_redo(out, inputs, Options(width=320), "the test") == "setting width changed since the test (640 -> 320)"
    assert why_redo(out, {**inputs, "names": ["a"]}, Options(), "the test") == "names changed since the test"
    assert why_redo(out, {**inputs, "more": source}, Options(), "the test") == "more is new since the test"
    source.write_text("2")
    assert why_redo(out, inputs, Options(), "the test") == "in.json changed since the test"
    source.unlink()
    assert why_redo(out, inputs, Options(), "the test") == "in.json is gone since the test"


def test_readers_refuse_a_stale_output_in_one_line(tmp_path):
    out, source = tmp_path / "poses3d.json", tmp_path / "poses2d.json"
    source.write_text("1")
    out.write_text("{}")
    assert stale_reason(out, {"poses2d.json": source}) is None        # no record: taken as it is
    write_record(out, "the reconstruction", {"poses2d.json": source}, {"tau": 0.2})
    check_fresh(out, {"poses2d.json": source, "unrecorded": source}, "mvm reconstruct S")
    source.write_text("2")
    with pytest.raises(InputError) as e:
        check_fresh(out, {"poses2d.json": source}, "mvm reconstruct S")
    assert str(e.value) == (f"{out}: out of date: poses2d.json changed since the reconstruction: "
                            "run `mvm reconstruct S` first")


@pytest.mark.parametrize("kind", ["fifo", "folder", "garbage", "not an object", "other format", "huge", "link"])
def test_a_record_that_cannot_be_read_is_no_record(tmp_path, kind):
    """A record that is a FIFO (never read: no hang), a folder, not JSON, of another format,
    larger than a record can be, or a link (mvm writes records in place: a link, even to a record
    that would match, is not this output's) makes its output out of date, never a traceback."""
    from mvm.io.provenance import RECORD_MAX_BYTES, read_record, record_path, why_redo, write_record

    output = tmp_path / "poses3d.json"
    output.write_text("{}")
    record = record_path(output)
    if kind == "fifo":
        os.mkfifo(record)
    elif kind == "folder":
        record.mkdir()
    elif kind == "link":
        elsewhere = tmp_path / "elsewhere" / record.name
        elsewhere.parent.mkdir()
        write_record(elsewhere.parent / output.name, "the output", {})
        assert read_record(elsewhere.parent / output.name) is not None
        record.symlink_to(elsewhere)
    else:
        record.write_bytes({"garbage": b"\xff{", "not an object": b"[1, 2]",
                            "other format": b'{"format": "x", "inputs": {}}',
                            "huge": b'{"format": "mvm.inputs/1", "inputs": {}, "pad": "' + b"x" * RECORD_MAX_BYTES
                            + b'"}'}[kind])
    assert read_record(output) is None
    assert why_redo(output, {}, None, "the output") is not None
