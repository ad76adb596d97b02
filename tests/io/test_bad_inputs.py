"""The corpus of malformed inputs (``tests/data/bad``): each gives exactly its error line,
through the reader and through the command line; file names never lead out of the scene."""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import tomllib
from click.testing import CliRunner

from mvm.errors import InputError

from helpers import DATA, random_cameras, standing_poses

BAD = DATA / "bad"
EXPECTED = tomllib.loads((BAD / "expected.toml").read_text())


def _readers():
    from mvm.io.calib_toml import read_calib_toml
    from mvm.io.coco import read_coco_keypoints
    from mvm.io.colmap import read_colmap
    from mvm.io.openpifpaf import read_openpifpaf_frame
    from mvm.io.openpose import read_openpose_frame
    from mvm.io.panoptic_calib import read_panoptic_calibration
    from mvm.io.scene_dir import read_poses3d, read_scene
    from mvm.io.trajectory import read_trajectory
    from mvm.io.trc import read_trc
    from mvm.settings.tables import load_config

    return {"coco": read_coco_keypoints, "colmap_bin": read_colmap, "colmap_txt": read_colmap,
            "scene": read_scene, "openpose": read_openpose_frame, "openpifpaf": read_openpifpaf_frame,
            "calib_toml": read_calib_toml, "trajectory": read_trajectory,
            "panoptic_calib": read_panoptic_calibration, "trc": read_trc, "config": load_config,
            "poses3d": read_poses3d}


CASES = [(reader, case, line) for reader, table in sorted(EXPECTED.items()) for case, line in sorted(table.items())]


def test_every_corpus_file_has_its_line():
    on_disk = {(p.parent.name, p.name) for p in BAD.glob("*/*")}
    listed = {(reader, case) for reader, case, _ in CASES}
    assert on_disk == listed
    assert set(EXPECTED) == set(_readers())
    assert len(CASES) >= 80


@pytest.mark.parametrize("reader, case, line", CASES, ids=[f"{r}/{c}" for r, c, _ in CASES])
def test_reader_gives_the_exact_line(reader, case, line, monkeypatch):
    monkeypatch.chdir(BAD)
    with pytest.raises(InputError) as info:
        _readers()[reader](Path(reader) / case)
    assert str(info.value) == line


def _cli(args, cwd: Path):
    from mvm.cli.main import main

    old = os.getcwd()
    os.chdir(cwd)
    try:
        return CliRunner().invoke(main, args, catch_exceptions=False)
    finally:
        os.chdir(old)


SCENES = [(case, line) for reader, case, line in CASES if reader == "scene"]
CONFIGS = [(case, line) for reader, case, line in CASES if reader == "config"]


@pytest.mark.parametrize("case, line", SCENES, ids=[c for c, _ in SCENES])
def test_cli_reconstruct_bad_scene(case, line, tmp_path):
    shutil.copytree(BAD / "scene" / case, tmp_path / "scene" / case)
    result = _cli(["reconstruct", f"scene/{case}"], tmp_path)
    assert result.exit_code == 2
    errors = [text for text in result.stderr.splitlines() if text.startswith("mvm: error:")]
    assert errors == [f"mvm: error: {line}"]
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "scene" / case / "mvm" / "poses3d.json").exists()


@pytest.mark.parametrize("case, line", CONFIGS, ids=[c for c, _ in CONFIGS])
def test_cli_bad_config(case, line):
    result = _cli(["reconstruct", "--config", f"config/{case}", "scene/not_in_model"], BAD)
    assert result.exit_code == 2
    assert result.stderr.strip() == f"mvm: error: {line}"


# --- names from inputs never lead out of the scene -------------------------------------------------

@pytest.mark.parametrize("name, ok", [
    ("f0000.jpg", True), ("cam1/000012.jpg", True), ("sub/../f0000.jpg", True), ("a..b.jpg", True),
    ("../f0000.jpg", False), ("../../etc/passwd", False), ("a/../../b.jpg", False), ("/etc/passwd", False),
    ("C:\\frames\\x.jpg", False), ("..\\..\\x.jpg", False), ("..", False), (".", False), ("", False),
    ("a\x00b.jpg", False),
])
def test_name_problem(name, ok):
    from mvm.io.paths import name_problem

    assert (name_problem(name) is None) == ok


def _scene(root: Path) -> Path:
    from mvm.core.scene import Poses2D
    from mvm.io.scene_dir import write_scene

    cams = random_cameras(np.random.default_rng(1), 3)
    X = standing_poses(1)[0]
    cam = np.einsum("vij,nj->vni", cams.R, X) + cams.t[:, None]
    xy = cam[..., :2] / cam[..., 2:] * 1000.0 + cams.K[:, None, :2, 2]
    kp = np.concatenate([xy, np.full((3, 17, 1), 0.9)], axis=2)
    write_scene(root, cams, Poses2D(kp, np.arange(3), np.arange(1, 4), np.full(3, 0.9), None))
    return root


def test_frame_symlink_leading_out_is_refused(tmp_path):
    from mvm.io.scene_dir import read_scene

    scene = _scene(tmp_path / "scene")
    outside = tmp_path / "secret.jpg"
    outside.write_bytes(b"not yours")
    (scene / "frames").mkdir()
    (scene / "frames" / "f0001.jpg").symlink_to(outside)
    with pytest.raises(InputError) as info:
        read_scene(scene)
    assert str(info.value) == (f"{scene / 'poses2d.json'}: images[1].file_name: 'f0001.jpg' leads outside "
                               "the scene directory through a symbolic link")


def test_frames_folder_symlink_leading_out_is_refused(tmp_path):
    from mvm.io.scene_dir import read_scene

    scene = _scene(tmp_path / "scene")
    (tmp_path / "elsewhere").mkdir()
    (scene / "frames").symlink_to(tmp_path / "elsewhere")
    with pytest.raises(InputError, match=r"images\[0\]\.file_name: 'f0000\.jpg' leads outside"):
        read_scene(scene)


def test_symlinks_inside_the_scene_are_followed(tmp_path):
    from mvm.io.scene_dir import read_scene

    scene = _scene(tmp_path / "scene")
    (scene / "images").mkdir()
    (scene / "images" / "f0001.jpg").write_bytes(b"jpeg")
    (scene / "frames").mkdir()
    (scene / "frames" / "f0001.jpg").symlink_to(scene / "images" / "f0001.jpg")
    assert len(read_scene(scene).poses) == 3


def test_resolve_in(tmp_path):
    from mvm.io.paths import resolve_in

    root = tmp_path / "scene" / "frames"
    root.mkdir(parents=True)
    assert resolve_in(root, "a/b.jpg", "poses2d.json", "images[0].file_name") == root / "a" / "b.jpg"
    for name in ("../x.jpg", "/x.jpg"):
        with pytest.raises(InputError, match=r"^poses2d\.json: images\[0\]\.file_name: "):
            resolve_in(root, name, "poses2d.json", "images[0].file_name")
    (root / "up").symlink_to(tmp_path)
    with pytest.raises(InputError, match="through a symbolic link"):
        resolve_in(root, "up/x.jpg", "poses2d.json", "images[0].file_name", scene=tmp_path / "scene")


def test_coco_names_checked_without_a_scene(tmp_path):
    """The COCO reader refuses leading-out names by itself (rig folders, detection imports)."""
    from mvm.io.coco import read_coco_keypoints

    doc = {"images": [{"id": 1, "file_name": "../../x.jpg"}], "annotations": []}
    (tmp_path / "p.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"images\[0\]\.file_name: path '\.\./\.\./x\.jpg' leads outside"):
        read_coco_keypoints(tmp_path / "p.json")
