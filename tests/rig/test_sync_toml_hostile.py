"""A rig's ``sync.toml`` is read whole or refused in one line, exit 2: an offset too large to be
a rig's (2^63 - 1 used to wrap around and drop the camera, 10^30 was an OverflowError), one that
moves a camera past the others' frames (with or without --frames), and a ``sync.toml`` that is
not a regular file of sane size (a link to nothing, a FIFO, a folder, 2 MB). The true offsets
of the simulation are read as written, and shift each camera onto the reference's instants."""
from __future__ import annotations

import os
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.rig import rig
from mvm.errors import InputError
from mvm.io.rig_simulation import write_rig_simulation
from mvm.io.sync_toml import write_sync_toml
from mvm.rig.rigdir import read_rig
from mvm.sim.rig_scene import RigSimConfig, simulate_rig

FRAMES = 12


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    root = tmp_path_factory.mktemp("rig") / "rig"
    sim = simulate_rig(RigSimConfig(cameras=3, people=1, frames=FRAMES, offsets=(0, 3, -2), seed=3))
    write_rig_simulation(root, sim)
    return root, sim


def _copy(base, tmp_path):
    shutil.copytree(base[0], tmp_path / "rig")
    return tmp_path / "rig"


def _one_line(result, *words):
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1, result.output
    assert "Traceback" not in result.output
    for word in words:
        assert word in lines[0], lines[0]


def test_the_true_offsets_shift_each_camera_onto_the_reference(base, tmp_path):
    root = _copy(base, tmp_path)
    truth = dict(zip(base[1].calibration.cameras.names, (int(o) for o in base[1].sync_offsets)))
    write_sync_toml(root / "sync.toml", truth)
    data = read_rig(root)
    assert data.offsets == truth
    plain = read_rig(root, sync=False)
    for v, name in enumerate(data.calibration.cameras.names):   # each camera's frames, moved by its offset
        shifted = np.unique(data.frames[data.detections.instant[data.detections.view == v]])
        unshifted = np.unique(plain.frames[plain.detections.instant[plain.detections.view == v]])
        assert shifted.tolist() == (unshifted + truth[name]).tolist()


@pytest.mark.parametrize("value, words", [
    (2 ** 63 - 1, ["cam_02", "more than the 1,000,000,000 frames"]),
    (10 ** 30, ["cam_02", "more than the 1,000,000,000 frames"]),
    (-(2 ** 63), ["cam_02", "more than the 1,000,000,000 frames"]),
    (10 ** 6, ["cam_02", "beyond the videos' length"]),
    (-(10 ** 9), ["cam_02", "beyond the videos' length"]),
])
@pytest.mark.parametrize("frames", [None, "0:6"])
def test_an_offset_no_rig_can_have_is_one_line(base, tmp_path, value, words, frames):
    root = _copy(base, tmp_path)
    (root / "sync.toml").write_text(f"[offsets]\ncam_01 = 0\ncam_02 = {value}\ncam_03 = 0\n")
    with pytest.raises(InputError) as info:
        read_rig(root, frames=frames)
    for word in ["sync.toml", "[offsets].cam_02", *words]:
        assert word in str(info.value), str(info.value)
    _one_line(CliRunner().invoke(rig, ["reconstruct", str(root), "--no-refine", "--workers", "1"]),
              "sync.toml", *words)
    assert not (root / "mvm").exists()


@pytest.mark.parametrize("kind, words", [
    ("dangling link", ["a symbolic link to nothing"]), ("folder", ["directory"]), ("fifo", ["FIFO"]),
    ("2 MB", ["not a rig's offsets"]), ("empty", ["[offsets]", "missing"]), ("binary", ["UTF-8"])])
def test_a_sync_toml_that_is_not_a_small_regular_file_is_one_line(base, tmp_path, kind, words):
    root = _copy(base, tmp_path)
    path = root / "sync.toml"
    if kind == "dangling link":
        path.symlink_to(tmp_path / "gone.toml")
    elif kind == "folder":
        path.mkdir()
    elif kind == "fifo":
        if not hasattr(os, "mkfifo"):
            pytest.skip("no FIFOs on this system")
        os.mkfifo(path)
    elif kind == "2 MB":
        path.write_text("[offsets]\ncam_01 = 0\ncam_02 = 0\ncam_03 = 0\n" + "#" * 2_000_000 + "\n")
    elif kind == "empty":
        path.write_text("")
    else:
        path.write_bytes(b"\xff\xfe\x00[offsets]")
    with pytest.raises(InputError) as info:
        read_rig(root)
    for word in ["sync.toml", *words]:
        assert word in str(info.value), str(info.value)
    _one_line(CliRunner().invoke(rig, ["reconstruct", str(root), "--no-refine", "--workers", "1"]), "sync.toml")
    assert not (root / "mvm").exists()
