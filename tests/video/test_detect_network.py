"""``mvm detect --checkpoint``: the network runs at the size it was trained at, or at
``--input-size``, without an autograd graph."""
import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

pytest.importorskip("torch", reason="torch is an optional dependency")


@pytest.fixture(scope="module")
def tiny_net(tmp_path_factory):
    from helpers import tiny_network

    return tiny_network(tmp_path_factory.mktemp("net"), input_size=96)[0]


@pytest.fixture
def scene(tmp_path):
    rng = np.random.default_rng(0)
    (tmp_path / "frames").mkdir()
    for i in range(3):
        cv2.imwrite(str(tmp_path / "frames" / f"{i:04d}.jpg"), rng.integers(0, 255, (360, 640, 3), dtype=np.uint8))
    return tmp_path


def _sizes_run(monkeypatch):
    import torch

    import mvm.net.evaluate as evaluate

    real, seen = evaluate.run_model, []

    def run_model(model, image, input_size, *args):
        seen.append((input_size, torch.is_grad_enabled()))
        return real(model, image, input_size, *args)

    monkeypatch.setattr(evaluate, "run_model", run_model)
    return seen


@pytest.mark.parametrize("given, expected", [([], 96), (["--input-size", "160"], 160)])
def test_detect_checkpoint_runs_at_the_trained_size(scene, tiny_net, monkeypatch, given, expected):
    from mvm.cli.video import detect_cmd

    seen = _sizes_run(monkeypatch)
    result = CliRunner().invoke(detect_cmd, [str(scene), "--checkpoint", str(tiny_net), *given])
    assert result.exit_code == 0, result.output
    assert seen == [(expected, False)] * 3                 # 3 frames, no autograd graph
    info = json.loads((scene / "poses2d.json").read_text())["info"]
    assert info["input_size"] == expected


def test_input_size_is_bounded_and_goes_with_a_checkpoint(scene):
    from mvm.cli.video import detect_cmd

    result = CliRunner().invoke(detect_cmd, [str(scene), "--input-size", "8", "--checkpoint", "x.pt"])
    assert result.exit_code == 2 and result.stderr.strip() == "mvm: error: --input-size: must be >= 16, got 8"
    result = CliRunner().invoke(detect_cmd, [str(scene), "--input-size", "320", "--detector", "rtmo"])
    assert result.exit_code == 2
    assert result.stderr.strip() == "mvm: error: --input-size: sizes mvm's network: goes with --checkpoint"
    assert not (scene / "poses2d.json").exists()
