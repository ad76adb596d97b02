"""Outputs are as readable as the process umask says: 0644 files and 0755 folders under umask
022, 0600 and 0700 under 077 (the writers' private temporary files must not leak their mode)."""
import os
import stat

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.io.files import atomic_write_bytes, atomic_write_json
from mvm.io.outputs import atomic_replace_dir

pytestmark = pytest.mark.skipif(os.name != "posix", reason="file modes are POSIX")

EXPECTED = {0o022: (0o644, 0o755), 0o077: (0o600, 0o700), 0o002: (0o664, 0o775)}


@pytest.fixture(params=sorted(EXPECTED))
def umask(request):
    previous = os.umask(request.param)
    try:
        yield request.param
    finally:
        os.umask(previous)


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def _check_tree(root, umask: int, mine: bool = True) -> int:
    """Every file and folder under ``root`` (and ``root``, when ``mine``: made by mvm) has the
    umask's mode; returns how many were checked."""
    file_mode, dir_mode = EXPECTED[umask]
    checked = 0
    for path in [root, *root.rglob("*")][0 if mine else 1:]:
        if path.is_symlink():
            continue
        expected = dir_mode if path.is_dir() else file_mode
        assert _mode(path) == expected, f"{path}: {oct(_mode(path))}, expected {oct(expected)} under umask {oct(umask)}"
        checked += 1
    return checked


def test_process_umask_is_read_without_change(umask):
    from mvm.io.files import new_dir_mode, new_file_mode, process_umask

    assert process_umask() == umask
    assert process_umask() == umask                     # unchanged by reading it
    assert (new_file_mode(), new_dir_mode()) == EXPECTED[umask]


def test_atomic_writers_give_the_umask_mode(tmp_path, umask):
    atomic_write_json(tmp_path / "a.json", {"x": 1})
    atomic_write_bytes(tmp_path / "b.bin", b"x")
    atomic_write_bytes(tmp_path / "b.bin", b"y")          # replacing an existing file
    atomic_replace_dir(lambda d: (d / "inside.txt").write_text("x") and (d / "sub").mkdir(), tmp_path / "set")
    atomic_replace_dir(lambda d: (d / "inside.txt").write_text("y"), tmp_path / "set")
    assert _check_tree(tmp_path / "set", umask) == 3     # set/, inside.txt, its marker
    assert _mode(tmp_path / "a.json") == EXPECTED[umask][0]
    assert _mode(tmp_path / "b.bin") == EXPECTED[umask][0]


def test_pipeline_outputs_give_the_umask_mode(tmp_path, umask):
    """A simulated scene (sparse/, poses2d.json), its reconstruction (poses3d.json), report.html,
    the overlay folder and video, a .trc and an exported data set (annotations.json)."""
    from mvm.cli.net import export_cmd
    from mvm.cli.report import overlay_cmd, report_cmd
    from mvm.cli.scene import reconstruct
    from mvm.cli.sim import simulate_cmd
    from mvm.io.trc import write_trc

    scene = tmp_path / "scene"
    runner = CliRunner()
    for command, args in ((simulate_cmd, [str(scene), "--people", "2", "--frames", "20"]),
                          (reconstruct, [str(scene), "--workers", "1"]),
                          (report_cmd, [str(scene), "--frames", "0"]),
                          (overlay_cmd, [str(scene), "--every", "10"]),
                          (overlay_cmd, [str(scene), "--every", "10", "-o", str(tmp_path / "overlay.mp4")]),
                          (export_cmd, [str(scene), "--out", str(tmp_path / "dataset"), "--link", "none"])):
        result = runner.invoke(command, args)
        assert result.exit_code == 0, (command.name, result.output)
    write_trc(tmp_path / "track.trc", np.zeros((3, 17, 3)), [f"m{j}" for j in range(17)], 30.0)
    for name in ("scene/poses2d.json", "scene/mvm/poses3d.json", "scene/mvm/report.html", "overlay.mp4",
                 "track.trc", "dataset/annotations.json"):
        assert (tmp_path / name).is_file(), name
    assert (tmp_path / "scene" / "sparse").is_dir() and (tmp_path / "scene" / "mvm" / "overlay").is_dir()
    assert _check_tree(tmp_path, umask, mine=False) > 12


@pytest.fixture(scope="module")
def tiny_net(tmp_path_factory):
    """A tiny trained network -> (checkpoint, an image)."""
    from helpers import tiny_network

    checkpoint, images = tiny_network(tmp_path_factory.mktemp("net"))
    return checkpoint, images[0]


def test_predictions_give_the_umask_mode(tmp_path, umask, tiny_net):
    from mvm.cli.net import predict_cmd

    checkpoint, image = tiny_net
    result = CliRunner().invoke(predict_cmd, [str(image), "--checkpoint", str(checkpoint), "-o", str(tmp_path / "p")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "p" / "predictions.json").is_file()
    assert _check_tree(tmp_path / "p", umask) >= 3


def test_downloaded_model_gets_the_umask_mode(tmp_path, umask):
    from mvm.video.models import download

    served = tmp_path / "served.onnx"
    served.write_bytes(b"onnx" * 100)
    target = download(served.as_uri(), tmp_path / "cache" / "model.onnx")
    assert target.read_bytes() == served.read_bytes()
    assert _mode(target) == EXPECTED[umask][0]
