"""The network learns, for real, on a CPU: synthetic renders of people with 3D supervision.

Renders small images of capsule people over textured backgrounds (``mvm.net.render``),
trains a narrow ResNet-18 at 96 px for a few hundred steps, and checks on held-out renders
that OKS AP and the relative depth error improve well beyond the untrained network.
About a minute on two CPU cores; set ``MVM_SKIP_LEARNING=1`` to skip it.
"""
import os

import pytest
import torch

from mvm.net import render
from mvm.net.evaluate import evaluate
from mvm.net.model import PoseNet
from mvm.net.train import DataSource, TrainConfig, read_checkpoint, train

SIZE = 96
STEPS = 600

pytestmark = pytest.mark.skipif(os.environ.get("MVM_SKIP_LEARNING") == "1", reason="MVM_SKIP_LEARNING=1")


def test_network_learns_pose_and_depth(tmp_path):
    train_set = render.synthetic_dataset(tmp_path / "train", 300, (SIZE, SIZE), persons=(1, 2), seed=100,
                                         distance=(1.8, 3.5))
    val_set = render.synthetic_dataset(tmp_path / "val", 40, (SIZE, SIZE), persons=(1, 2), seed=900,
                                       distance=(1.8, 3.5))
    cfg = TrainConfig(train=(DataSource(str(train_set)),), backbone="resnet18", stride=8, width=16,
                      input_size=SIZE, lr=0.05, momentum=0.9, batch_size=8, ema_decay=0.05, steps=STEPS,
                      background_weight=0.2, out_dir=str(tmp_path / "run"), checkpoint_every=STEPS,
                      log_every=100, device="cpu", seed=0, threads=1)
    torch.manual_seed(cfg.seed)
    before = evaluate(PoseNet(cfg.model_spec), val_set, input_size=SIZE)

    state, meta = read_checkpoint(train(cfg))
    model = PoseNet(cfg.model_spec)
    model.load_state_dict(state["ema"])
    after = evaluate(model, val_set, input_size=SIZE)
    print(f"\nuntrained: {before}\ntrained:   {after}\n{meta['images_per_second']:.1f} images/s")

    assert before["AP"] == 0.0 and before["AP50"] == 0.0 and before["matched"] == 0
    assert after["AP50"] > 0.08 and after["AP"] > 0.005
    assert after["matched"] >= 8                                    # of 60 people in the held-out set
    assert after["depth_error_gt2d"] < 0.25 * before["depth_error_gt2d"]
    assert after["depth_error_gt2d"] < 1.1 * after["depth_error_flat"]
