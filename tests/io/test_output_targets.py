"""Outputs never take what is not theirs: whatever lies where a command's output goes (a FIFO,
a device, a link to a file elsewhere, a user's file of the same name) is refused in one line
(exit 2) or left as it is; never replaced, never written through. Every command of the CLI is
walked: each one that writes is run against a FIFO and a link in place of its output, or named
with the reason it is not run here."""
from __future__ import annotations

import json
import os
import shutil
import stat
import sys
from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.main import main

from helpers import dead_pid

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="FIFOs, device nodes and flock are POSIX")

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "rig"))
from test_faults import write_location_inputs  # noqa: E402

from calibration_writers import known_cameras, write_qca  # noqa: E402


def invoke(*args) -> click.testing.Result:
    """``mvm ARGS`` in process; never a traceback."""
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output
    return result


def one_line_exit_2(result, *words) -> str:
    errors = [line for line in result.output.splitlines() if line.startswith("mvm: error:")]
    assert result.exit_code == 2 and len(errors) == 1, result.output
    for word in words:
        assert str(word) in errors[0], (word, errors[0])
    return errors[0]


# ------------------------------------------------------------------ what is put where an output goes

def place(kind: str, path: Path, outside: Path) -> None:
    """Put a ``kind`` where ``path`` goes: a FIFO, a link to the file ``outside`` (which must
    not change), a character device (root only), or a user's file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "link":
        outside.write_text("a file elsewhere")
        path.symlink_to(outside)
    elif kind == "device":
        if os.geteuid() != 0:
            pytest.skip("making a device node needs root")
        os.mknod(path, 0o600 | stat.S_IFCHR, os.makedev(1, 3))      # a null device, in tmp_path only
    else:
        path.write_text("the user's own file")


def intact(kind: str, path: Path, outside: Path) -> bool:
    """Whether what :func:`place` put at ``path`` is still there, unchanged."""
    mode = os.lstat(path).st_mode
    if kind == "fifo":
        return stat.S_ISFIFO(mode)
    if kind == "link":
        return stat.S_ISLNK(mode) and outside.read_text() == "a file elsewhere"
    if kind == "device":
        return stat.S_ISCHR(mode)
    return stat.S_ISREG(mode) and path.read_text() == "the user's own file"


# ------------------------------------------------------------------------------- fixtures

@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A reconstructed scene with frames, a rig with its 2D poses, a rig to convert a
    calibration into (and the Qualisys file), and a short video."""
    import cv2

    root = tmp_path_factory.mktemp("targets")
    found = write_location_inputs(root)
    convert_rig = root / "convert_rig"
    (convert_rig / "videos").mkdir(parents=True)
    for name in ("cam01", "cam02", "cam03"):
        (convert_rig / "videos" / f"{name}.mp4").write_bytes(b"")
    found["convert_rig"] = convert_rig
    found["qca"] = write_qca(root / "lab.qca.txt", known_cameras(3))
    found["video"] = video = root / "clip.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10, (64, 48))
    rng = np.random.default_rng(0)
    for _ in range(12):
        writer.write(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    writer.release()
    found["image"] = next(iter(sorted((found["scene"] / "frames").iterdir())))
    return found


def _scene_copy(inputs, work: Path) -> Path:
    """A copy of the reconstructed scene without its record: the next run writes again."""
    scene = work / "scene"
    shutil.copytree(inputs["scene"], scene, symlinks=True)
    (scene / "mvm" / "poses3d.inputs.json").unlink()
    (scene / "mvm" / "poses3d.json").unlink()
    return scene


# --------------------------------------------------------------- every command of the CLI

def cli_commands() -> list[str]:
    """Every command of ``mvm``, subcommands of groups as ``"rig calibrate"``."""
    ctx = click.Context(main)
    found = []

    def walk(group, prefix):
        for name in group.list_commands(ctx):
            command = group.get_command(ctx, name)
            if isinstance(command, click.Group):
                walk(command, prefix + (name,))
            else:
                found.append(" ".join(prefix + (name,)))
    walk(main, ())
    return found


#: For each command that writes: ``(inputs, work) -> (arguments, the output file or folder)``.
WRITES = {
    "bench": lambda i, w: (["bench", "--quick", "-o", w / "d"], w / "d" / "paper_tables.md"),
    "demo": lambda i, w: (["demo", "-o", w / "d", "--frames", "20", "--people", "1"],
                          w / "d" / "scene.groundtruth.json"),
    "export": lambda i, w: (["export", i["scene"], "--out", w / "set", "--link", "copy"], w / "set"),
    "overlay": lambda i, w: (["overlay", i["scene"], "-o", w / "o.mp4", "--every", "3", "--max-width", "32"],
                             w / "o.mp4"),
    "report": lambda i, w: (["report", i["scene"], "-o", w / "r.html"], w / "r.html"),
    "reconstruct": lambda i, w: (["reconstruct", _scene_copy(i, w), "--workers", "1", "--no-refine"],
                                 w / "scene" / "mvm" / "poses3d.json"),
    "rig reconstruct": lambda i, w: (["rig", "reconstruct", i["rig"], "-o", w / "out", "--no-refine",
                                      "--workers", "1"], w / "out"),
    "rig calibrate": lambda i, w: (["rig", "calibrate", i["convert_rig"], "--convert", i["qca"], "-o",
                                    w / "c.toml"], w / "c.toml"),
    "simulate": lambda i, w: (["simulate", w / "s", "--people", "1", "--frames", "20"], w / "s" / "poses2d.json"),
    "frames": lambda i, w: (["frames", i["video"], "-o", w / "album", "--blur-ratio", "0"],
                            w / "album" / "frames.json"),
    "evaluate cvar": lambda i, w: (["evaluate", "cvar", i["scene"], "--out", w / "c.json"], w / "c.json"),
    "predict": lambda i, w: (["predict", i["image"], "--checkpoint", w / "none.pt", "-o", w / "p"],
                             w / "p" / "predictions.json"),
}

#: The commands not run here, and why.
NOT_RUN = {
    "config": "prints the settings; writes nothing",
    "status": "reads the manifest; writes nothing (its records: test_status_sees_every_unusable_record)",
    "batch": "writes each clip's stage outputs through the same writers as frames, detect and reconstruct",
    "detect": "needs a detector; its poses2d.json goes through the atomic writer (test_atomic_writer_refuses)",
    "sfm": "needs COLMAP's matches; its sparse/ is a folder set (atomic_replace_dir) and its report goes "
           "through the atomic writer",
    "run": "frames, sfm, detect and reconstruct in a row: walked one by one",
    "train": "trains a network; its checkpoints go through the atomic writer",
    "evaluate 3dpw": "needs the 3DPW data set; writes its --out through the atomic writer as evaluate cvar",
    "evaluate coco": "needs COCO images or detections; writes its --out through the atomic writer as evaluate cvar",
    "rig detect": "needs a detector; its pose/*.json go through the atomic writer",
    "rig synchronize": "its sync.toml goes through the atomic writer (tested with the rig's sync files)",
}


def test_every_command_is_walked():
    commands = set(cli_commands())
    assert not set(WRITES) & set(NOT_RUN)
    assert commands == set(WRITES) | set(NOT_RUN), commands ^ (set(WRITES) | set(NOT_RUN))


@pytest.mark.parametrize("kind", ["fifo", "link"])
@pytest.mark.parametrize("command", sorted(WRITES))
def test_a_fifo_or_a_link_in_place_of_an_output_is_refused(inputs, tmp_path, command, kind):
    args, target = WRITES[command](inputs, tmp_path)
    outside = tmp_path / "elsewhere" / "file.txt"
    outside.parent.mkdir()
    place(kind, target, outside)
    result = invoke(*args)
    one_line_exit_2(result)
    assert intact(kind, target, outside), (command, kind)
    assert sorted(p.name for p in outside.parent.iterdir()) == (["file.txt"] if kind == "link" else [])


def test_atomic_writer_refuses(tmp_path):
    """The one check under every file output: refused before the temporary is made."""
    from mvm.io.files import OutputError, atomic_write_text

    for kind in ("fifo", "link", "device"):
        target, outside = tmp_path / kind, tmp_path / f"{kind}.outside"
        try:
            place(kind, target, outside)
        except pytest.skip.Exception:
            continue
        with pytest.raises(OutputError, match="refusing to write: is a"):
            atomic_write_text(target, "x")
        assert intact(kind, target, outside)
        assert [p.name for p in tmp_path.iterdir() if ".mvm-tmp-" in p.name] == []


# ------------------------------------------- 1. a device given as an output stays a device

@pytest.mark.parametrize("kind", ["device", "fifo", "link"])
def test_rig_calibrate_report_and_simulated_truth_never_replace_a_device(inputs, tmp_path, kind):
    outside = tmp_path / "outside.txt"
    toml = tmp_path / "calib" / "c.toml"
    place(kind, toml, outside)
    one_line_exit_2(invoke("rig", "calibrate", inputs["convert_rig"], "--convert", inputs["qca"], "-o", toml), toml)
    assert intact(kind, toml, outside)
    page = tmp_path / "page" / "x.html"
    place(kind, page, outside)
    one_line_exit_2(invoke("report", inputs["scene"], "-o", page), page)
    assert intact(kind, page, outside)
    truth = tmp_path / "r.groundtruth.json"
    place(kind, truth, outside)
    one_line_exit_2(invoke("simulate", tmp_path / "r", "--rig", "--cameras", "3", "--people", "1", "--frames", "20"),
                    truth)
    assert intact(kind, truth, outside)
    assert not (tmp_path / "r").exists()                      # refused before any write


# ------------------------------------------------ 2. a refused export keeps the data set

@pytest.mark.parametrize("fault", ["poses3d.json gone", "poses3d.json stale"])
def test_a_refused_export_leaves_the_previous_data_set_whole(inputs, tmp_path, fault):
    scene = tmp_path / "scene"
    shutil.copytree(inputs["scene"], scene, symlinks=True)
    out = tmp_path / "set"
    assert invoke("export", scene, "--out", out, "--link", "copy").exit_code == 0
    before = (out / "annotations.json").read_bytes()
    images = sorted(p.relative_to(out) for p in out.rglob("*"))
    assert json.loads(before)["annotations"]
    if fault == "poses3d.json gone":
        (scene / "mvm" / "poses3d.json").unlink()
    else:
        poses2d = json.loads((scene / "poses2d.json").read_text())
        poses2d["annotations"] = poses2d["annotations"][1:]
        (scene / "poses2d.json").write_text(json.dumps(poses2d))
    result = invoke("export", scene, "--out", out, "--link", "copy")
    assert result.exit_code == 2, result.output
    assert (out / "annotations.json").read_bytes() == before
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == images


# ----------------------------------------------- 3. a user's file of the same name is kept

def test_simulate_keeps_a_users_poses2d_and_sparse(tmp_path):
    scene = tmp_path / "scene"
    place("user", scene / "poses2d.json", tmp_path / "x")
    one_line_exit_2(invoke("simulate", scene, "--people", "1", "--frames", "20"), scene / "poses2d.json")
    assert intact("user", scene / "poses2d.json", tmp_path / "x")
    assert not (scene / "sparse").exists()
    (scene / "poses2d.json").unlink()
    (scene / "sparse").mkdir()
    (scene / "sparse" / "cameras.txt").write_text("# a hand-made COLMAP model")
    (scene / "sparse" / "notes.md").write_text("how I made it")
    one_line_exit_2(invoke("simulate", scene, "--people", "1", "--frames", "20"), scene / "sparse")
    assert sorted(p.name for p in (scene / "sparse").iterdir()) == ["cameras.txt", "notes.md"]
    assert not (scene / "poses2d.json").exists()
    # mvm's own scene, made again: its files are its own
    fresh = tmp_path / "fresh"
    assert invoke("simulate", fresh, "--people", "1", "--frames", "20").exit_code == 0
    first = (fresh / "poses2d.json").read_bytes()
    assert invoke("simulate", fresh, "--people", "2", "--frames", "20").exit_code == 0
    assert (fresh / "poses2d.json").read_bytes() != first


def test_frames_keeps_a_users_album(inputs, tmp_path):
    album = tmp_path / "album"
    place("user", album / "frames.json", tmp_path / "x")
    one_line_exit_2(invoke("frames", inputs["video"], "-o", album, "--blur-ratio", "0"), album / "frames.json")
    assert intact("user", album / "frames.json", tmp_path / "x") and not (album / "frames").exists()
    mine = tmp_path / "mine"
    place("user", mine / "frames" / "frame_00001.jpg", tmp_path / "x")
    one_line_exit_2(invoke("frames", inputs["video"], "-o", mine, "--blur-ratio", "0"), mine / "frames")
    assert intact("user", mine / "frames" / "frame_00001.jpg", tmp_path / "x")
    assert sorted(p.name for p in mine.iterdir()) == ["frames"]


@pytest.mark.parametrize("name", ["paper_tables.md", "clips.csv"])
def test_bench_keeps_a_users_tables(tmp_path, name):
    place("user", tmp_path / "d" / name, tmp_path / "x")
    one_line_exit_2(invoke("bench", "--quick", "-o", tmp_path / "d"), tmp_path / "d" / name)
    assert intact("user", tmp_path / "d" / name, tmp_path / "x")
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == [name]


def test_predict_keeps_a_users_predictions(inputs, tmp_path):
    place("user", tmp_path / "p" / "predictions.json", tmp_path / "x")
    one_line_exit_2(invoke("predict", inputs["image"], "--checkpoint", tmp_path / "none.pt", "-o", tmp_path / "p"),
                    tmp_path / "p" / "predictions.json")
    assert intact("user", tmp_path / "p" / "predictions.json", tmp_path / "x")


def test_demo_keeps_a_users_ground_truth(tmp_path):
    truth = tmp_path / "d" / "scene.groundtruth.json"
    place("user", truth, tmp_path / "x")
    one_line_exit_2(invoke("demo", "-o", tmp_path / "d", "--frames", "20", "--people", "1"), truth)
    assert intact("user", truth, tmp_path / "x")
    assert not (tmp_path / "d" / "scene").exists()


# ---------------------------------------------- 4. a planted lock link creates nothing

def test_a_planted_lock_link_creates_no_file_outside(inputs, tmp_path):
    rig = tmp_path / "rig"
    shutil.copytree(inputs["rig"], rig)
    target = tmp_path / "outside" / "x"
    target.parent.mkdir()
    (rig / ".mvm.lock").symlink_to(target)
    one_line_exit_2(invoke("rig", "reconstruct", rig, "--no-refine", "--workers", "1", "--force"), ".mvm.lock")
    assert not os.path.lexists(target) and list(target.parent.iterdir()) == []
    assert not (rig / "mvm").exists()


# ---------------------------------------------------------- 7. records that lie

BAD_RECORDS = ["garbage", "fifo", "1 GB", "folder", "nested 1020 deep", "link"]


def _spoil(record: Path, how: str) -> None:
    sound = json.loads(record.read_text())
    record.unlink()
    if how == "garbage":
        record.write_bytes(b"\x00\xffnot json{")
    elif how == "fifo":
        os.mkfifo(record)
    elif how == "1 GB":
        with open(record, "wb") as f:
            f.truncate(2**30)                                 # sparse: no disk used
    elif how == "folder":
        record.mkdir()
    elif how == "nested 1020 deep":                            # a sound record but for its depth
        text = json.dumps(sound)
        assert '"settings": {' in text
        record.write_text(text.replace('"settings": {', '"settings": {"deep": ' + '{"a": ' * 1020 + "1"
                                       + "}" * 1020 + ", ", 1))
    else:
        record.with_name("elsewhere.json").write_text("{}")
        record.symlink_to(record.with_name("elsewhere.json"))


@pytest.fixture(scope="module")
def batch_root(tmp_path_factory):
    from batch.test_batch import make_root
    from mvm.batch import run_batch

    root = tmp_path_factory.mktemp("records") / "root"
    make_root(root, n=1, people=(2, 2), frames=(12, 12), broken=False)
    assert not run_batch(root, ("reconstruct",), workers=1).failed
    return root


@pytest.mark.parametrize("how", BAD_RECORDS)
def test_status_sees_every_unusable_record(batch_root, tmp_path, how):
    from mvm.batch import batch_status

    root = tmp_path / "root"
    shutil.copytree(batch_root, root, symlinks=True)
    assert batch_status(root).stale == []
    (record,) = root.rglob("poses3d.inputs.json")
    _spoil(record, how)
    (stale,) = batch_status(root).stale
    assert stale[1] == "reconstruct" and "record is unusable" in stale[2]


@pytest.mark.parametrize("how", BAD_RECORDS)
def test_reconstruct_redoes_an_output_whose_record_is_unusable(inputs, tmp_path, how):
    scene = tmp_path / "scene"
    shutil.copytree(inputs["scene"], scene, symlinks=True)
    _spoil(scene / "mvm" / "poses3d.inputs.json", how)
    result = invoke("reconstruct", scene, "--workers", "1", "--no-refine")
    if how == "folder":                                       # not mvm's to delete: refused in one line
        one_line_exit_2(result, "poses3d.inputs.json", "directory")
        return
    assert result.exit_code == 0, result.output
    record = scene / "mvm" / "poses3d.inputs.json"
    assert stat.S_ISREG(os.lstat(record).st_mode) and json.loads(record.read_text())["format"] == "mvm.inputs/1"


def test_frames_with_a_frame_deleted_are_made_again(inputs, tmp_path):
    album = tmp_path / "album"
    assert invoke("frames", inputs["video"], "-o", album, "--blur-ratio", "0").exit_code == 0
    names = [f["file_name"] for f in json.loads((album / "frames.json").read_text())["frames"]]
    (album / "frames" / names[3]).unlink()
    result = invoke("frames", inputs["video"], "-o", album, "--blur-ratio", "0")
    assert result.exit_code == 0 and f"frames/{names[3]} is gone" in result.output, result.output
    assert sorted(p.name for p in (album / "frames").iterdir()) == sorted(names)


def test_a_leftover_record_temporary_is_removed(inputs, tmp_path):
    scene = tmp_path / "scene"
    shutil.copytree(inputs["scene"], scene, symlinks=True)
    (scene / "mvm" / "poses3d.inputs.json").unlink()       # killed while writing the record: redone
    gone = dead_pid()
    for name in ("poses3d.json", "poses3d.inputs.json"):
        (scene / "mvm" / f".{name}.mvm-tmp-{gone}-k2j4h_x.tmp").write_text("{half")
    assert invoke("reconstruct", scene, "--workers", "1", "--no-refine").exit_code == 0
    assert sorted(p.name for p in (scene / "mvm").iterdir()) == ["poses3d.inputs.json", "poses3d.json", "timings.json"]


def test_writing_into_a_folder_knows_its_own_names(tmp_path):
    """The decision for names mvm chooses inside a user's folder: a user's file is refused
    before anything is written, mvm's own (listed in the marker, or with a record beside it) is
    replaced, and a killed writer's temporary of a name is removed."""
    from mvm.io.files import OutputError, atomic_write_text
    from mvm.io.outputs import OUTPUT_MARKER, writing_into

    folder = tmp_path / "d"
    place("user", folder / "clips.csv", tmp_path / "x")
    with pytest.raises(OutputError, match="clips.csv: exists and mvm did not write it"):
        with writing_into(folder, ["table.md", "clips.csv"]):
            raise AssertionError("never reached")
    assert sorted(p.name for p in folder.iterdir()) == ["clips.csv"]            # no marker, no lock left
    (folder / "clips.csv").unlink()
    (folder / f".table.md.mvm-tmp-{dead_pid()}-k2j4h_x.tmp").write_text("half")
    (folder / ".table.md.old.tmp").write_text("a user's")
    for _ in range(2):                                                          # the second run: its own files
        with writing_into(folder, ["table.md", "clips.csv"]):
            atomic_write_text(folder / "table.md", "t")
            atomic_write_text(folder / "clips.csv", "c")
    assert sorted(p.name for p in folder.iterdir()) == [OUTPUT_MARKER, ".table.md.old.tmp", "clips.csv", "table.md"]
    assert json.loads((folder / OUTPUT_MARKER).read_text()) == ["clips.csv", "table.md"]
    (folder / "index.json").write_text("{}")                                    # made by a stage: its record
    (folder / "index.inputs.json").write_text("{}")
    with writing_into(folder, ["index.json"]):
        atomic_write_text(folder / "index.json", "[]")


@pytest.mark.parametrize("kind", ["device", "fifo", "link"])
def test_rig_calibrate_from_people_refuses_a_device_before_any_work(tmp_path, kind):
    rig = tmp_path / "r"
    assert invoke("simulate", rig, "--rig", "--cameras", "3", "--people", "2", "--frames", "20",
                  "--intrinsics-only").exit_code == 0
    out, outside = tmp_path / "null", tmp_path / "outside.txt"
    place(kind, out, outside)
    one_line_exit_2(invoke("rig", "calibrate", rig, "--from-people", "-o", out), out, "refusing to write")
    assert intact(kind, out, outside)


def test_a_failed_run_leaves_no_folder_nor_name_behind(tmp_path):
    from mvm.io.outputs import OUTPUT_MARKER, writing_into

    folder = tmp_path / "new"
    with pytest.raises(RuntimeError):
        with writing_into(folder, ["a.csv"]):
            raise RuntimeError("the work failed")
    assert not folder.exists()
    place("user", tmp_path / "old" / "notes.txt", tmp_path / "x")
    with pytest.raises(RuntimeError):
        with writing_into(tmp_path / "old", ["a.csv"]):
            raise RuntimeError("the work failed")
    assert sorted(p.name for p in (tmp_path / "old").iterdir()) == ["notes.txt"]
    with pytest.raises(RuntimeError):
        with writing_into(tmp_path / "old", ["a.csv", "b.csv"]):
            (tmp_path / "old" / "a.csv").write_text("1")
            raise RuntimeError("the work failed half-way")
    assert json.loads((tmp_path / "old" / OUTPUT_MARKER).read_text()) == ["a.csv"]


def test_a_killed_runs_temporary_is_removed_by_the_next_write_into_its_folder(tmp_path):
    """Every atomic write's temporary is named after its writer's process: one whose process is
    gone (a run killed while writing) is deleted by the next write into that folder, whatever
    the file; a live writer's stays, and so does a file that only looks like one."""
    from mvm.io.files import atomic_output, atomic_write_text

    gone = dead_pid()
    dead = tmp_path / f".cams.toml.mvm-tmp-{gone}-abc123.tmp"
    dead_download = tmp_path / f".model.onnx.mvm-tmp-{gone}-x9.part"
    live = tmp_path / f".cams.toml.mvm-tmp-{os.getpid()}-def456.tmp"
    other = tmp_path / ".cams.toml.mvm-tmp-notes.tmp"
    for f in (dead, dead_download, live, other):
        f.write_text("x")
    with atomic_output(tmp_path / "report.html") as tmp:
        assert tmp.name.startswith(f".report.html.mvm-tmp-{os.getpid()}-")
        tmp.write_text("page")
    assert not dead.exists() and not dead_download.exists() and live.exists() and other.exists()
    atomic_write_text(tmp_path / "cams.toml", "calibration")
    assert (tmp_path / "cams.toml").read_text() == "calibration" and (tmp_path / "report.html").exists()
