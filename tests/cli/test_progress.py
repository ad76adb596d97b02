"""A progress bar on every step that can take more than 2 s: the library functions report
their progress through callbacks, and the commands draw them on a terminal."""
import numpy as np
import pytest
from click.testing import CliRunner

from helpers import random_cameras, standing_poses


def test_render_frames_reports_every_frame(tmp_path):
    from mvm.sim.mannequin_video import render_frames

    cameras = random_cameras(np.random.default_rng(0), 4, width=96, height=64, focal=80.0)
    calls = []
    paths = render_frames(tmp_path, cameras, standing_poses(2), progress=lambda *a: calls.append(a))
    assert len(paths) == 4 and calls == [(0, 4), (1, 4), (2, 4), (3, 4), (4, 4)]


def test_demo_reports_rendering_and_reconstruction(tmp_path):
    from mvm.eval.demo import run_demo
    from mvm.sim.simulate import SimConfig

    calls = []
    run_demo(tmp_path, SimConfig(people=2, frames=20), progress=lambda *a: calls.append(a))
    assert calls == [("reconstructing", 0, 1), ("reconstructing", 1, 1)]


def test_train_reports_every_step(tmp_path):
    pytest.importorskip("torch", reason="torch is an optional dependency")
    from mvm.net.train import train
    from mvm.net.train_config import load_config
    from mvm.sim import people_images as images

    data = images.synthetic_dataset(tmp_path / "data", 2, (64, 64), seed=5)
    config = tmp_path / "tiny.toml"
    config.write_text(f'[model]\nbackbone = "resnet18"\nstride = 16\nwidth = 8\n[data]\ninput_size = 64\n'
                      f'[[data.train]]\nannotations = "{data}"\n[optim]\nsteps = 3\nbatch_size = 2\n'
                      f'[output]\nout_dir = "{tmp_path / "run"}"\ndevice = "cpu"\n')
    calls = []
    train(load_config(config, {"log_every": 2}), progress=lambda *a: calls.append(a))
    assert [(step, steps) for step, steps, _ in calls] == [(1, 3), (2, 3), (3, 3)]
    assert [losses is None for _, _, losses in calls] == [True, False, False]
    assert np.isfinite(calls[-1][2]["total"])


def _recorded(monkeypatch, module):
    """Replace the progress bar of ``module`` by a recorder: -> the list of ``(stage, done, total)``."""
    from contextlib import contextmanager

    calls = []

    @contextmanager
    def recorder(*columns):
        yield lambda *a: calls.append(a)

    monkeypatch.setattr(module, "stage_progress", recorder)
    return calls


@pytest.mark.parametrize("command, args", [("simulate", ["--frames", "20", "--people", "1", "--render"]),
                                           ("demo", ["--frames", "20", "--people", "1", "--render"])])
def test_simulate_and_demo_render_with_a_bar(tmp_path, monkeypatch, command, args):
    import mvm.cli.sim as sim

    calls = _recorded(monkeypatch, sim)
    where = [str(tmp_path / "s")] if command == "simulate" else ["-o", str(tmp_path / "d")]
    result = CliRunner().invoke(getattr(sim, f"{command}_cmd"), [*where, *args])
    assert result.exit_code == 0, result.output
    assert [c for c in calls if c[0] == "rendering"] == [("rendering", i, 20) for i in range(21)]


def test_train_command_draws_its_steps(tmp_path, monkeypatch):
    pytest.importorskip("torch", reason="torch is an optional dependency")
    from contextlib import contextmanager

    import mvm.cli.net as net

    from helpers import tiny_network

    calls = []

    @contextmanager
    def recorder():
        yield lambda *a: calls.append(a)

    monkeypatch.setattr(net, "train_progress", recorder)
    tiny_network(tmp_path, steps=2)
    assert [(step, steps) for step, steps, _ in calls] == [(1, 2), (2, 2)]


@pytest.mark.slow
def test_sfm_reports_each_stage_and_every_registered_frame(tmp_path):
    """COLMAP on 20 rendered frames (about 30 s)."""
    from mvm.cli.sim import simulate_cmd
    from mvm.video.sfm import SFM_STAGES, SfmOptions, run_sfm

    result = CliRunner().invoke(simulate_cmd, [str(tmp_path / "s"), "--frames", "20", "--people", "1", "--render"])
    assert result.exit_code == 0, result.output
    calls = []
    report = run_sfm(tmp_path / "s", SfmOptions(max_features=1024, max_image_size=640), force=True,
                     progress=lambda *a: calls.append(a))
    features, matching, mapping = SFM_STAGES
    assert calls[:4] == [(features, 0, None), (features, 20, 20), (matching, 0, None), (matching, 20, 20)]
    registered = [done for stage, done, total in calls[4:] if stage == mapping and total == 20]
    assert registered[:2] == [0, 2] and registered == sorted(registered)
    assert registered[-1] == len(report.registered) >= 18
