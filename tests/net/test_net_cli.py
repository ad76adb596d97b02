"""The ``export``, ``train`` and ``predict`` commands."""
import json

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.net import _parse_sets, export_cmd, predict_cmd, train_cmd
from mvm.core.camera import project_persons
from mvm.core.scene import Cameras, Persons3D, Poses2D
from mvm.errors import InputError
from mvm.sim import people_images as images


@pytest.mark.parametrize("command", [export_cmd, train_cmd, predict_cmd])
def test_help(command):
    result = CliRunner().invoke(command, ["--help"])
    assert result.exit_code == 0 and "Usage" in result.output


def _scene_dir(tmp_path):
    import cv2

    from mvm.io.scene_dir import poses3d_document, write_poses3d, write_scene

    rng = np.random.default_rng(0)
    people, K = images.random_scene(rng, 2, (160, 120), distance=(3.0, 4.0))
    V = 3
    R = np.tile(np.eye(3), (V, 1, 1))
    t = np.array([[0.1 * v, 0, 0] for v in range(V)])
    cams = Cameras(np.tile(K, (V, 1, 1)), R, t, np.tile([160, 120], (V, 1)), tuple(f"{v:04d}.jpg" for v in range(V)))
    kps = [project_persons(people, K, R[v], t[v], (160, 120))[0] for v in range(V)]
    kp2d = np.concatenate(kps)
    kp2d[:, :, 2] = np.minimum(kp2d[:, :, 2], 1.0)
    view = np.repeat(np.arange(V), len(people))
    poses = Poses2D(kp2d, view, np.arange(1, len(view) + 1), np.ones(len(view)))
    scene = tmp_path / "scene1"
    write_scene(scene, cams, poses)
    (scene / "frames").mkdir()
    for name in cams.names:
        cv2.imwrite(str(scene / "frames" / name), np.zeros((120, 160, 3), np.uint8))
    P = len(people)
    persons = Persons3D(people, np.ones((P, 17)), [np.array([p, p + P, p + 2 * P]) for p in range(P)],
                        np.full((P, 17), 3), np.zeros((P, 17), int), np.zeros(P))
    (scene / "mvm").mkdir()
    write_poses3d(scene / "mvm" / "poses3d.json", poses3d_document(persons, poses, {}))
    return scene


def test_export_command(tmp_path):
    scene = _scene_dir(tmp_path)
    result = CliRunner().invoke(export_cmd, [str(scene), "--out", str(tmp_path / "ds"), "--link", "copy"])
    assert result.exit_code == 0, result.output
    assert "3 images" in result.output
    data = json.loads((tmp_path / "ds" / "annotations.json").read_text())
    assert len(data["annotations"]) == 6
    assert all((tmp_path / "ds" / im["file_name"]).is_file() for im in data["images"])


def test_export_rerun_keeps_an_up_to_date_dataset_and_redoes_a_changed_one(tmp_path):
    """In the dataset, annotations.inputs.json records what it was made from: the same scenes and
    options keep it untouched; a changed option, a changed reconstruction, a copied frame that
    changed or --force export again, saying why; a run where a scene failed leaves the previous
    data set whole, and a first one writes the scenes it read without a record."""
    scene, other = _scene_dir(tmp_path), tmp_path / "broken"
    other.mkdir()
    ds, runner = tmp_path / "ds", CliRunner()

    def export(*args):
        result = runner.invoke(export_cmd, [str(scene), "--out", str(ds), "--link", "copy", *args])
        return result, (ds / "annotations.json").stat().st_mtime_ns if (ds / "annotations.json").exists() else None

    result, made = export()
    assert result.exit_code == 0 and "export: made: no output yet" in result.stderr
    assert json.loads((ds / "annotations.inputs.json").read_text())["settings"] == \
        {"link": "copy", "min_keypoints": 3, "complete": False, "out": ds.resolve().as_posix()}
    result, again = export()
    assert result.exit_code == 0 and "export: kept (up to date)" in result.stderr and again == made
    result, again = export("--min-keypoints", "5")
    assert "made: setting min_keypoints changed since the export (3 -> 5)" in result.stderr and again != made
    frame = scene / "frames" / "0001.jpg"
    frame.write_bytes(frame.read_bytes() + b"\0")
    result, made = export("--min-keypoints", "5")
    assert "made: frames changed since the export" in result.stderr
    assert (ds / "images" / "scene1" / "0001.jpg").read_bytes() == frame.read_bytes()
    poses3d = scene / "mvm" / "poses3d.json"
    poses3d.write_text(poses3d.read_text().replace("\n", "\n "))
    result, again = export("--min-keypoints", "5")
    assert "made: poses3d.json changed since the export" in result.stderr and again != made
    result, _ = export("--min-keypoints", "5", "--force")
    assert "made: forced" in result.stderr
    before = {p.name: p.read_bytes() for p in ds.iterdir() if p.is_file()}
    result = runner.invoke(export_cmd, [str(scene), str(other), "--out", str(ds)])
    assert result.exit_code == 2 and "left as it was" in result.stderr      # the previous data set is kept whole
    assert {p.name: p.read_bytes() for p in ds.iterdir() if p.is_file()} == before
    fresh = tmp_path / "fresh"                                 # a first export writes the scenes it could read
    result = runner.invoke(export_cmd, [str(scene), str(other), "--out", str(fresh)])
    assert result.exit_code == 2 and "3 images, 6 annotations from 1 scene(s)" in result.output
    assert not (fresh / "annotations.inputs.json").exists()


@pytest.mark.parametrize("link", ["symlink", "none"])
def test_export_redoes_a_dataset_whose_scene_or_itself_moved(tmp_path, link):
    """The images are named after the scene's folder and linked (or named, --link none)
    relative to the dataset: a scene renamed, or the dataset moved, exports again rather than
    keeping images of the old name and links that lead nowhere."""
    scene, ds, runner = _scene_dir(tmp_path), tmp_path / "ds", CliRunner()

    def export(scene_dir, out):
        result = runner.invoke(export_cmd, [str(scene_dir), "--out", str(out), "--link", link])
        assert result.exit_code == 0, result.output
        return result.stderr

    assert "export: made" in export(scene, ds)
    assert "export: kept (up to date)" in export(scene, ds)
    renamed = scene.rename(tmp_path / "renamed")
    assert "made: scenes changed since the export" in export(renamed, ds)
    images = json.loads((ds / "annotations.json").read_text())["images"]
    assert all(im["file_name"].startswith("images/renamed/") for im in images) if link == "symlink" else \
        all("renamed" in im["file_name"] for im in images)
    assert all((ds / im["file_name"]).is_file() for im in images)
    moved = ds.rename(tmp_path / "moved")
    assert "made: setting out changed" in export(renamed, moved)
    assert all((moved / im["file_name"]).is_file()
               for im in json.loads((moved / "annotations.json").read_text())["images"])


def test_export_without_poses3d_is_an_input_error(tmp_path):
    (tmp_path / "empty").mkdir()
    result = CliRunner().invoke(export_cmd, [str(tmp_path / "empty"), "--out", str(tmp_path / "ds")])
    assert result.exit_code == 2
    assert result.stderr.splitlines()[0] == f"mvm: error: {tmp_path / 'empty' / 'mvm' / 'poses3d.json'}: not found: " \
                                            "reconstruct the scene first (mvm reconstruct)"


def test_train_and_predict_commands(tmp_path):
    data = images.synthetic_dataset(tmp_path / "data", 4, (64, 64), seed=5)
    config = tmp_path / "tiny.toml"
    config.write_text(f"""
[model]
backbone = "resnet18"
stride = 16
width = 8
[data]
input_size = 64
[[data.train]]
annotations = "{data}"
[optim]
steps = 2
batch_size = 2
[output]
out_dir = "{tmp_path / 'run'}"
device = "cpu"
""")
    result = CliRunner().invoke(train_cmd, [str(config), "--set", "steps=3", "--set", "lr=0.01"])
    assert result.exit_code == 0, result.output
    assert "step 3" in result.output and "images/s" in result.output
    ckpt = tmp_path / "run" / "checkpoint-0000003.pt"
    image = tmp_path / "data" / "images" / "000000.png"
    result = CliRunner().invoke(predict_cmd, [str(image), "--checkpoint", str(ckpt), "--out", str(tmp_path / "p")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "p" / "predictions.json").is_file()
    result = CliRunner().invoke(predict_cmd, [str(image), "--checkpoint", str(tmp_path / "missing.pt")])
    assert result.exit_code == 2 and "missing.pt: file not found" in result.output
    (tmp_path / "missing.pt").write_bytes(b"")
    result = CliRunner().invoke(predict_cmd, [str(image), "--checkpoint", str(tmp_path / "missing.pt")])
    assert result.exit_code == 2 and "missing.json: checkpoint metadata not found" in result.output
    (tmp_path / "empty.png").write_bytes(b"")
    result = CliRunner().invoke(predict_cmd, [str(tmp_path / "empty.png"), "--checkpoint", str(ckpt)])
    assert result.exit_code == 2 and result.output.count("\n") == 1 and "empty.png: empty file" in result.output


def test_parse_sets():
    assert _parse_sets(("lr=0.01", "backbone=resnet18", "flip = 0")) == {"lr": 0.01, "backbone": "resnet18", "flip": 0}
    with pytest.raises(InputError, match="KEY=VALUE"):
        _parse_sets(("lr",))


def test_train_refuses_an_out_dir_among_its_inputs_before_any_work(tmp_path):
    data = images.synthetic_dataset(tmp_path / "data", 2, (64, 64), seed=5)
    config = tmp_path / "tiny.toml"
    config.write_text(f'[[data.train]]\nannotations = "{data}"\n[output]\ndevice = "cpu"\n')
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    for out_dir, problem in ((data.parent, "is an input of this run"), (tmp_path, "contains the input"),
                             (data.parent / "runs", "lies inside the input folder")):
        result = CliRunner().invoke(train_cmd, [str(config), "--set", f"out_dir='{out_dir}'"])
        assert result.exit_code == 2, result.output
        assert result.stderr.strip().splitlines() == [result.stderr.strip()]
        assert result.stderr.startswith(f"mvm: error: {out_dir}: {problem}")
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before     # nothing written


def test_predict_input_size_is_bounded_before_any_work(tmp_path):
    from mvm.net.predict import MAX_INPUT_SIZE, MIN_INPUT_SIZE, predict

    image = tmp_path / "a.png"
    image.write_bytes(b"")
    result = CliRunner().invoke(predict_cmd, [str(image), "--checkpoint", str(tmp_path / "none.pt"),
                                              "--input-size", "100000"])
    assert result.exit_code == 2 and result.stderr.strip() == "mvm: error: --input-size: must be <= 4096, got 100000"
    for size in (100000, 0, MAX_INPUT_SIZE + 1, MIN_INPUT_SIZE - 1):
        with pytest.raises(InputError, match=f"--input-size: expected a long edge of 16 to 4096 px, got {size}"):
            predict([image], tmp_path / "none.pt", input_size=size)           # before the checkpoint is read
    option = next(p for p in predict_cmd.params if p.name == "input_size")
    assert (option.type.bounds.ge, option.type.bounds.le) == (MIN_INPUT_SIZE, MAX_INPUT_SIZE)


@pytest.mark.parametrize("kind", ["fifo", "huge", "malformed", "folder", "link"])
def test_export_never_trusts_a_hostile_record(tmp_path, kind):
    """An annotations.inputs.json in the dataset that is a FIFO (no hang), huge, not JSON, a
    folder or a link to a record that would match is no record: the dataset is exported again,
    and the new record is a file of its own (the linked one is left as it was)."""
    import os

    from mvm.io.provenance import RECORD_MAX_BYTES

    scene, ds = _scene_dir(tmp_path), tmp_path / "ds"
    runner = CliRunner()
    assert runner.invoke(export_cmd, [str(scene), "--out", str(ds)]).exit_code == 0
    record = ds / "annotations.inputs.json"
    good = record.read_bytes()
    record.unlink()
    elsewhere = tmp_path / "elsewhere.json"
    elsewhere.write_bytes(good)
    if kind == "fifo":
        os.mkfifo(record)
    elif kind == "huge":
        record.write_bytes(good[:-2] + b" " * RECORD_MAX_BYTES + good[-2:])
    elif kind == "malformed":
        record.write_bytes(good[: len(good) // 2])
    elif kind == "folder":
        record.mkdir()
    else:
        record.symlink_to(elsewhere)
    result = runner.invoke(export_cmd, [str(scene), "--out", str(ds)])
    assert result.exit_code == 0, result.output
    assert "export: made: its record is unusable (annotations.inputs.json" in result.stderr
    assert record.is_file() and not record.is_symlink() and json.loads(record.read_text())["inputs"]
    assert elsewhere.read_bytes() == good
    assert "export: kept (up to date)" in runner.invoke(export_cmd, [str(scene), "--out", str(ds)]).stderr


def test_export_rerun_reads_each_input_once(tmp_path, monkeypatch):
    """Deciding whether a dataset is up to date hashes each input file once (frames just written
    are not in the hash cache, so a second hashing would read them all again)."""
    from collections import Counter

    from mvm.io import provenance

    scene, ds = _scene_dir(tmp_path), tmp_path / "ds"
    runner = CliRunner()
    assert runner.invoke(export_cmd, [str(scene), "--out", str(ds), "--link", "copy"]).exit_code == 0
    read, hash_file = Counter(), provenance._hash_file

    def counted(path):
        read[path] += 1
        return hash_file(path)

    monkeypatch.setattr(provenance, "_hash_file", counted)
    result = runner.invoke(export_cmd, [str(scene), "--out", str(ds), "--link", "copy"])
    assert "export: kept (up to date)" in result.stderr
    frames = sorted((scene / "frames").iterdir())
    assert frames and all(read[f] == 1 for f in frames) and set(read.values()) == {1}, read
