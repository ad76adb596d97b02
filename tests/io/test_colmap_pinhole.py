"""A COLMAP model of pinhole cameras is read without pycolmap, to the same numbers as pycolmap
reads it; models with lenses or rigs of several cameras still go through pycolmap."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import mvm
from mvm.errors import InputError
from mvm.io import colmap
from mvm.io.colmap_check import check_model
from mvm.io.colmap_records import CAMERA_MODELS, pycolmap_camera_models

from helpers import random_cameras


def _both(model_dir: Path):
    """(the model built from the checks' records, pycolmap's), or the one-line refusals."""
    def attempt(read):
        try:
            return read()
        except InputError as e:
            return str(e)

    return (attempt(lambda: colmap._pinhole_model(check_model(model_dir), model_dir)),
            attempt(lambda: colmap._parse(model_dir)))


def _same(a, b) -> None:
    for field in ("K", "R", "t", "size"):
        np.testing.assert_array_equal(getattr(a.cameras, field), getattr(b.cameras, field), err_msg=field)
    assert a.cameras.names == b.cameras.names and a.models == b.models and a.unregistered == b.unregistered
    assert sorted(map(tuple, a.points3d)) == sorted(map(tuple, b.points3d))
    assert not any(map(len, a.cameras.distortion)) and not any(map(len, b.cameras.distortion))


@pytest.mark.parametrize("binary", [True, False])
def test_written_models_read_as_pycolmap_reads_them(tmp_path, binary):
    cams = random_cameras(np.random.default_rng(5), 7)
    points = np.random.default_rng(6).normal(size=(5, 3))
    colmap.write_colmap(tmp_path, cams, binary=binary, points3d=points)
    ours, theirs = _both(tmp_path)
    _same(ours, theirs)
    np.testing.assert_allclose(ours.cameras.R, cams.R, atol=1e-12)


def test_legacy_text_models_of_both_pinholes_and_their_refusals(tmp_path):
    (tmp_path / "cameras.txt").write_text("1 SIMPLE_PINHOLE 640 480 500 320 240\n2 PINHOLE 640 480 500 510 321 239\n")
    (tmp_path / "points3D.txt").write_text("1 0.5 0.2 3.0 255 0 0 0.5\n7 1.5 0.2 3.0 255 0 0 0.5\n")
    images = ("5 1 0 0 0 0 0 0 1 a.jpg\n\n2 0.7071068 0 0.7071068 0 0.5 0 2 2 b.jpg\n\n"
              "3 0.5 0.5 -0.5 0.5 0.5 1 2 1 c.jpg\n\n")
    (tmp_path / "images.txt").write_text(images)
    ours, theirs = _both(tmp_path)
    _same(ours, theirs)
    assert ours.cameras.names == ("b.jpg", "c.jpg", "a.jpg")                 # by image id
    np.testing.assert_array_equal(ours.cameras.K[1], [[500, 0, 320], [0, 500, 240], [0, 0, 1]])
    np.testing.assert_array_equal(ours.cameras.K[0], [[500, 0, 321], [0, 510, 239], [0, 0, 1]])
    # A quaternion far from unit length: pycolmap's matrix of it is no rotation; refused alike.
    (tmp_path / "images.txt").write_text(images.replace("0.7071068 0 0.7071068 0", "0.7071068 0.1 0.7071068 0.3"))
    ours, theirs = _both(tmp_path)
    assert ours == theirs == f"{tmp_path}: image 2: pose is not a finite rotation and translation"


def test_lenses_and_rigs_of_several_cameras_go_through_pycolmap(tmp_path):
    (tmp_path / "cameras.txt").write_text("1 SIMPLE_RADIAL 640 480 500 320 240 0.01\n")
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.jpg\n\n")
    (tmp_path / "points3D.txt").write_text("")
    assert colmap._pinhole_model(check_model(tmp_path), tmp_path) is None
    model = colmap.read_colmap(tmp_path)
    assert model.models == ("SIMPLE_RADIAL",)
    np.testing.assert_array_equal(model.cameras.distortion[0], [0.01, 0, 0, 0])           # OpenCV's k1 k2 p1 p2

    rig = tmp_path / "rig"
    rig.mkdir()
    (rig / "cameras.txt").write_text("1 PINHOLE 640 480 500 500 320 240\n2 PINHOLE 640 480 500 500 320 240\n")
    (rig / "rigs.txt").write_text("1 2 CAMERA 1 CAMERA 2 1 1 0 0 0 0.3 0 0\n")
    (rig / "frames.txt").write_text("1 1 1 0 0 0 0 0 2 2 CAMERA 1 1 CAMERA 2 2\n")
    (rig / "images.txt").write_text("1 1 0 0 0 0 0 2 1 a.jpg\n\n2 1 0 0 0 0.3 0 2 2 b.jpg\n\n")
    (rig / "points3D.txt").write_text("")
    assert colmap._pinhole_model(check_model(rig), rig) is None
    model = colmap.read_colmap(rig)
    np.testing.assert_allclose(model.cameras.t, [[0, 0, 2], [0.3, 0, 2]])   # the second camera's offset


def test_the_table_of_camera_models_is_pycolmaps():
    installed = pycolmap_camera_models()
    assert {k: installed[k] for k in CAMERA_MODELS if k in installed} == {
        k: v for k, v in CAMERA_MODELS.items() if k in installed}
    assert set(CAMERA_MODELS) <= set(installed)


def test_reconstructing_a_pinhole_scene_imports_neither_pycolmap_nor_opencv_nor_scipy(tmp_path):
    """Each costs 0.06-0.7 s to import: more than reconstructing a short video."""
    from mvm.io.scene_dir import write_scene
    from mvm.sim.simulate import SimConfig, simulate

    scene = simulate(SimConfig(people=2, frames=20, seed=1))[0]
    write_scene(tmp_path / "s", scene.cameras, scene.poses)
    code = ("import sys; from mvm.cli import main\n"
            "try:\n    main(['reconstruct', '--workers', '1', sys.argv[1]], standalone_mode=False)\n"
            "finally:\n    print(sorted({m.split('.')[0] for m in sys.modules} & {'pycolmap', 'cv2', 'scipy'}))")
    source = str(Path(mvm.__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([source, os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, "-c", code, str(tmp_path / "s")], capture_output=True, text=True,
                         env=env, timeout=120, check=False)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().splitlines()[-1] == "[]"
    assert (tmp_path / "s" / "mvm" / "poses3d.json").is_file()
