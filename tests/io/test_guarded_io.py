"""The one guarded way to open an input and to write an output.

Reads: a FIFO, a device, a folder, a file over the size limit and a link that leads out of
the scene are refused in one line before anything is read (no hang, no MemoryError).
Writes: a folder in the way, an output name taken by a folder, a read-only file system and a
full disk end in one line naming the path, exit status 2, with nothing half-written. The
commands that read frames (overlay, export, sfm) never follow a frame linked outside."""
from __future__ import annotations

import errno
import json
import os
import sys
import threading

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.main import main
from mvm.errors import InputError
from mvm.io import checks
from mvm.io.checks import load_json, read_bytes
from mvm.io.files import OutputError, atomic_write_json
from mvm.io.outputs import atomic_replace_dir, make_temporary_dir
from mvm.io.scene_dir import output_dir, write_scene
from mvm.sim.simulate import SimConfig, simulate

from helpers import run_at_once

posix_only = pytest.mark.skipif(sys.platform == "win32", reason="FIFOs and /dev/zero are POSIX")


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    """A small simulated scene directory (3 people, 10 frames) with frames/ images."""
    import cv2

    scene, _ = simulate(SimConfig(people=3, frames=10, seed=7))
    path = tmp_path_factory.mktemp("guard") / "scene"
    write_scene(path, scene.cameras, scene.poses)
    (path / "frames").mkdir()
    for name, (w, h) in zip(scene.cameras.names, scene.cameras.size):
        cv2.imwrite(str(path / "frames" / name), np.full((int(h), int(w), 3), 200, np.uint8))
    return path


def _copy(scene_dir, tmp_path):
    import shutil

    return shutil.copytree(scene_dir, tmp_path / "scene", symlinks=True)


def _run(*args):
    """(exit status, the ``mvm: error:`` lines) of a command; never a traceback."""
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output
    return result.exit_code, [line for line in result.output.splitlines() if line.startswith("mvm: error:")]


# ------------------------------------------------------------------------------- reads


@posix_only
def test_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "poses2d.json"
    os.mkfifo(fifo)
    outcome = []
    reader = threading.Thread(target=lambda: outcome.append(_refusal(fifo)), daemon=True)
    reader.start()
    reader.join(timeout=5)
    assert outcome == [f"{fifo}: is a FIFO (named pipe), expected a regular file"]


def _refusal(path, **kw):
    try:
        read_bytes(path, **kw)
    except InputError as e:
        return str(e)
    return "read"


@posix_only
def test_devices_folders_and_large_files_are_refused(tmp_path, monkeypatch):
    link = tmp_path / "zero.json"
    link.symlink_to("/dev/zero")
    assert _refusal(link) == f"{link}: is a character device, expected a regular file"
    assert _refusal(tmp_path) == f"{tmp_path}: is a directory, expected a file"
    big = tmp_path / "big.json"
    big.write_bytes(b" " * 3000)
    assert _refusal(big, limit=2048) == (f"{big}: 2.93 KiB, more than the 2 KiB limit for an input file "
                                         "(MVM_MAX_INPUT_MB)")
    monkeypatch.setattr(checks, "MAX_INPUT_BYTES", 1000)
    with pytest.raises(InputError, match="more than the 1000 bytes limit"):
        load_json(big)


def test_a_link_out_of_the_root_is_refused(tmp_path):
    outside = tmp_path / "secret.json"
    outside.write_text("{}")
    root = tmp_path / "scene"
    root.mkdir()
    (root / "inner.json").write_text("[1]")
    (root / "in.json").symlink_to(root / "inner.json")      # a link inside the scene is fine
    (root / "out.json").symlink_to(outside)
    (root / "loop.json").symlink_to(root / "loop.json")
    assert load_json(root / "in.json", root=root) == [1]
    with pytest.raises(InputError, match=r"out.json: leads outside .*scene through a symbolic link"):
        load_json(root / "out.json", root=root)
    with pytest.raises(InputError, match=r"loop.json: (cannot resolve|leads outside)"):
        load_json(root / "loop.json", root=root)


@posix_only
def test_reconstruct_refuses_a_fifo_and_a_link_out(scene_dir, tmp_path):
    path = _copy(scene_dir, tmp_path)
    poses2d = path / "poses2d.json"
    saved = tmp_path / "poses2d.json"
    poses2d.rename(saved)
    poses2d.symlink_to(saved)                               # a valid file, but outside the scene
    code, lines = _run("reconstruct", path)
    assert code == 2 and len(lines) == 1 and "poses2d.json: leads outside" in lines[0]
    poses2d.unlink()
    os.mkfifo(poses2d)
    code, lines = _run("reconstruct", path)
    assert code == 2 and lines == [f"mvm: error: {poses2d}: is a FIFO (named pipe), expected a regular file"]
    assert not (path / "mvm" / "poses3d.json").exists()


def test_frames_linked_outside_are_never_read(scene_dir, tmp_path):
    from mvm.net.supervision import export_supervision
    from mvm.report.load import load_result
    from mvm.report.overlay import ViewRenderer

    path = _copy(scene_dir, tmp_path)
    code, _ = _run("reconstruct", path)
    assert code == 0
    result = load_result(path)
    name = result.scene.cameras.names[0]
    secret = tmp_path / "secret.jpg"
    (path / "frames" / name).rename(secret)
    (path / "frames" / name).symlink_to(secret)
    with pytest.raises(InputError, match=f"file_name: '{name}' leads outside the scene"):
        load_result(path)                                   # report and overlay refuse the scene
    renderer = ViewRenderer(result)                         # a frame linked after reading
    image = renderer.render(0)
    assert renderer.missing_frames == 1                     # drawn on the neutral background
    assert not (image == 200).all()
    with pytest.raises(InputError, match=f"{name}: leads outside"):
        export_supervision([(result.scene, result.persons, path / "frames")], tmp_path / "data", link="copy")
    assert not (tmp_path / "data").exists()
    from mvm.io.images import check_frames

    with pytest.raises(InputError, match=f"{name}: leads outside"):         # what sfm checks first
        check_frames(path / "frames", [name], root=path)


# ------------------------------------------------------------------------------- writes


def test_output_folder_leading_out_or_taken_is_refused(scene_dir, tmp_path):
    path = _copy(scene_dir, tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (path / "mvm").symlink_to(elsewhere)
    code, lines = _run("reconstruct", path)
    assert code == 2 and len(lines) == 1
    assert lines[0].startswith(f"mvm: error: {path / 'mvm'}: refusing to write: leads outside")
    assert list(elsewhere.iterdir()) == []
    (path / "mvm").unlink()
    (path / "mvm").write_text("a file")
    code, lines = _run("reconstruct", path)
    assert (code, lines) == (2, [f"mvm: error: {path / 'mvm'}: cannot write: exists and is not a folder"])
    (path / "mvm").unlink()
    (path / "mvm" / "poses3d.json").mkdir(parents=True)
    code, lines = _run("reconstruct", path)
    assert (code, lines) == (2, [f"mvm: error: {path / 'mvm' / 'poses3d.json'}: cannot write: "
                                 "is a directory, expected a file"])
    with pytest.raises(InputError, match="leads outside the scene"):
        output_dir(path, "../x")


@pytest.mark.parametrize("err, text", [(errno.ENOSPC, "no space left on the device"),
                                       (errno.EROFS, "read-only file system"),
                                       (errno.EPERM, "operation not permitted")])
def test_os_errors_of_a_write_are_one_line(tmp_path, monkeypatch, err, text):
    out = tmp_path / "out.json"
    atomic_write_json(out, {"v": 1})

    def fail(*a, **k):
        raise OSError(err, os.strerror(err))

    monkeypatch.setattr("mvm.io.files.os.replace", fail)
    with pytest.raises(OutputError) as info:
        atomic_write_json(out, {"v": 2})
    assert str(info.value).startswith(f"{out}: cannot write: {text}")
    assert json.loads(out.read_text()) == {"v": 1}                   # the previous output stays
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]      # no temporary file left
    with pytest.raises(OutputError, match=f"cannot write: {text}"):
        atomic_replace_dir(lambda d: (d / "a").write_text("x"), tmp_path / "set")
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]


def test_a_full_disk_during_reconstruct_is_one_line(scene_dir, tmp_path, monkeypatch):
    path = _copy(scene_dir, tmp_path)

    def full(fd):                                           # the data reaches the disk at fsync
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("mvm.io.files.os.fsync", full)
    code, lines = _run("reconstruct", path)
    out = path / "mvm" / "poses3d.json"
    assert (code, lines) == (2, [f"mvm: error: {out}: cannot write: no space left on the device"])
    assert not out.exists() and not list((path / "mvm").glob(".*"))


def test_an_output_set_leaves_nothing_stale(tmp_path):
    target = tmp_path / "set"
    atomic_replace_dir(lambda d: [(d / f"{i}.txt").write_text("old") for i in range(3)], target)
    (make_temporary_dir(target) / "x").write_text("partial")   # what a killed run leaves
    atomic_replace_dir(lambda d: (d / "0.txt").write_text("new"), target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["set"]
    assert sorted(p.name for p in target.iterdir()) == [".mvm-output", "0.txt"]
    assert (target / "0.txt").read_text() == "new"

    def fails(d):
        (d / "0.txt").write_text("half")
        raise InputError(None, None, "boom")

    with pytest.raises(InputError):
        atomic_replace_dir(fails, target)
    assert (target / "0.txt").read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["set"]


def test_export_rerun_is_one_set(scene_dir, tmp_path):
    from mvm.net.supervision import export_supervision
    from mvm.report.load import load_result

    path = _copy(scene_dir, tmp_path)
    assert _run("reconstruct", path)[0] == 0
    result = load_result(path)
    out = tmp_path / "data"
    export_supervision([(result.scene, result.persons, path / "frames"),
                        (result.scene, result.persons, path / "frames")], out, link="copy")
    assert len(list((out / "images").iterdir())) == 2
    export_supervision([(result.scene, result.persons, path / "frames")], out, link="symlink")
    assert [p.name for p in (out / "images").iterdir()] == ["scene"]         # the second scene is gone
    linked = next((out / "images" / "scene").iterdir())
    assert linked.is_symlink() and linked.resolve() == (path / "frames" / linked.name).resolve()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="holds 'notes.txt', which mvm did not write there"):
        export_supervision([(result.scene, result.persons, path / "frames")], out)


def test_export_never_writes_over_its_inputs_nor_a_users_folder(scene_dir, tmp_path):
    path = _copy(scene_dir, tmp_path)
    assert _run("reconstruct", path)[0] == 0
    frames = sorted(p.name for p in (path / "frames").iterdir())
    thesis = tmp_path / "thesis"
    (thesis / "data").mkdir(parents=True)
    (thesis / "thesis.tex").write_text("chapter 1")
    for out, problem in ((path / "frames", "is an input of this run"), (path, "contains the input"),
                         (path / "mvm", "contains the input"), (path / "sparse" / "x", "lies inside the input"),
                         (thesis, "mvm did not make")):
        code, lines = _run("export", path, "--out", out)
        assert code == 2 and len(lines) == 1 and lines[0].startswith(f"mvm: error: {out}: ") and problem in lines[0]
    assert sorted(p.name for p in (path / "frames").iterdir()) == frames
    assert (thesis / "thesis.tex").read_text() == "chapter 1" and (thesis / "data").is_dir()
    # a user's folder named like a leftover beside the dataset stays
    (tmp_path / ".ds_sib.keep").mkdir()
    (tmp_path / ".ds_sib.keep" / "notes.txt").write_text("mine")
    for _ in range(2):
        assert _run("export", path, "--out", tmp_path / "ds_sib")[0] == 0
    assert (tmp_path / ".ds_sib.keep" / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".ds_sib.keep", "ds_sib", "scene", "thesis"]


def test_concurrent_exports_leave_one_complete_dataset(scene_dir, tmp_path):

    path = _copy(scene_dir, tmp_path)
    assert _run("reconstruct", path)[0] == 0
    out = tmp_path / "DS"
    assert 0 in run_at_once(["export", path, "--out", out, "--link", "copy"])
    data = json.loads((out / "annotations.json").read_text())
    assert len(data["images"]) == 10
    assert all((out / image["file_name"]).is_file() for image in data["images"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DS", "scene"]


@pytest.mark.parametrize("name", ["frames", "sparse", "poses2d.json", "./frames", "x/../frames/out", "sparse/0"])
def test_a_scene_output_name_naming_an_input_is_refused(scene_dir, tmp_path, name):
    path = _copy(scene_dir, tmp_path)
    before = {p.relative_to(path): p.read_bytes() for p in path.rglob("*") if p.is_file()}
    code, lines = _run("reconstruct", path, "--output-name", name)
    assert code == 2 and len(lines) == 1 and "is an input of the scene" in lines[0], lines
    assert {p.relative_to(path): p.read_bytes() for p in path.rglob("*") if p.is_file()} == before
