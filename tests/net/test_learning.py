"""The network learns, for real, on a CPU: synthetic renders of people with 3D supervision.

Renders small images of capsule people over textured backgrounds (``mvm.sim.people_images``),
trains the network of ``configs/train_cpu_tiny.toml`` (a narrow ResNet-18 at 96 px) for a few
hundred steps on one thread, and checks on held-out renders that OKS AP rises far above the
untrained network's and that the relative depth error falls far below the untrained
network's and below the flat baseline (every joint of a person at the same depth).
About 70 s on two CPU cores, so marked slow: ``pytest -m "not slow"`` leaves it out.
The longer run with the figures of ``docs/network.md`` is ``benchmarks/train_synthetic.py``.
"""
import pytest
import torch

from mvm.net.checkpoints import read_checkpoint
from mvm.net.evaluate import evaluate
from mvm.net.model import PoseNet
from mvm.net.train import train
from mvm.net.train_config import DataSource, load_config
from mvm.sim import people_images as images

from helpers import REPO

CONFIG = REPO / "configs" / "train_cpu_tiny.toml"
STEPS = 500
IMAGES = 500                                            # training renders; 40 held out

pytestmark = pytest.mark.slow


def test_network_learns_pose_and_depth(tmp_path):
    base = load_config(CONFIG)
    train_set, val_set = images.demo_datasets(tmp_path / "data", IMAGES, 40, base.input_size, seed=100)
    cfg = base.replace(train=(DataSource(str(train_set)),), val=None, steps=STEPS, checkpoint_every=STEPS,
                       out_dir=str(tmp_path / "run"), device="cpu", seed=0, threads=1)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        torch.manual_seed(cfg.seed)                        # the weights train() starts from
        before = evaluate(PoseNet(cfg.model_spec), val_set, input_size=cfg.input_size)
        state, meta = read_checkpoint(train(cfg))
        model = PoseNet(cfg.model_spec)
        model.load_state_dict(state["ema"])
        after = evaluate(model, val_set, input_size=cfg.input_size)
    finally:
        torch.set_num_threads(threads)
    print(f"\nuntrained: {before}\ntrained:   {after}\n{meta['images_per_second']:.1f} images/s")

    assert after["persons"] == before["persons"] >= 50
    # 2D: from nothing to most people found and assembled
    assert before["AP"] == 0.0 and before["AP50"] == 0.0 and before["matched"] == 0
    assert after["AP50"] > 0.45 and after["AP"] > 0.1
    assert after["matched"] >= 0.6 * after["persons"]
    # depth at the ground-truth keypoints: from noise to better than a flat person
    assert before["depth_error_gt2d"] > 3 * before["depth_error_flat"]
    assert after["depth_error_gt2d"] < 0.2 * before["depth_error_gt2d"]
    assert after["depth_error_gt2d"] < 0.9 * after["depth_error_flat"]
    # depth of the detected people, against the flat baseline on the same people and joints
    assert after["depth_error"] < 0.92 * after["depth_error_flat_matched"]
