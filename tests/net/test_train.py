"""Training mechanics: config, data augmentation, checkpoints (state_dict + JSON), resume, predict."""
import json
import time

import numpy as np
import pytest
import torch

from mvm.core.keypoints import FLIP_PERMUTATION
from mvm.errors import InputError
from mvm.net.checkpoints import latest_checkpoint, list_checkpoints, prune_checkpoints, read_checkpoint
from mvm.net.data import AugmentConfig, KeypointDataset, random_crop_flip, read_annotations
from mvm.net.ema import EMA
from mvm.net.metrics_log import finite_or_none, read_metrics_log
from mvm.net.predict import load_model, predict
from mvm.net.sampling import MixtureSampler
from mvm.net.train import learning_rate, train
from mvm.net.train_config import config_from_dict, load_config
from mvm.sim import people_images as images

from helpers import REPO


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    root = tmp_path_factory.mktemp("synthetic")
    return images.synthetic_dataset(root, 6, (64, 64), persons=(1, 2), seed=3, distance=(1.8, 3.0))


def _config(data, out, **kw):
    doc = {"model": {"backbone": "resnet18", "stride": 16, "width": 8},
           "data": {"input_size": 64, "train": [{"annotations": str(data)}]},
           "optim": {"lr": 0.01, "batch_size": 2, "steps": 3, "ema_decay": 0.1},
           "output": {"out_dir": str(out), "checkpoint_every": 2, "log_every": 1, "device": "cpu"}}
    for key, value in kw.items():
        doc["output" if key in ("val_every", "checkpoint_every", "keep_last", "keep_best") else "optim"][key] = value
    return config_from_dict(doc)


def test_config_files_parse(tmp_path):
    root = REPO / "configs"
    paper = load_config(root / "train_paper.toml")
    assert ((paper.lr, paper.momentum, paper.batch_size, paper.weight_decay, paper.ema_decay)
            == (1e-3, 0.95, 8, 0.0, 1e-3))
    assert ((paper.crop_min, paper.crop_max, paper.backbone, paper.stride, paper.upsample)
            == (0.95, 1.0, "resnet152", 8, 2))
    assert paper.model_spec.backbone_stride == 16 and paper.depth_loss == "image" and paper.keep_last > 0
    baseline = load_config(root / "train_paper_coco.toml")
    assert baseline.train == paper.train[:1] and baseline.model_spec == paper.model_spec and baseline.lr == paper.lr
    assert paper.train[0].start_step == 0 and paper.train[1].start_step > 0
    tiny = load_config(root / "train_cpu_tiny.toml", {"steps": 5})
    assert tiny.steps == 5 and tiny.backbone == "resnet18"
    with pytest.raises(InputError, match="unknown setting.*known: .*backbone"):
        config_from_dict({"optim": {"learning_rate": 1.0}})
    with pytest.raises(InputError, match="stride"):
        config_from_dict({"model": {"stride": 32}})


def test_crop_and_flip_move_keypoints_with_the_image():
    image = np.zeros((80, 100, 3), np.uint8)
    kp = np.zeros((1, 17, 3))
    kp[0, :, 0] = np.linspace(30, 70, 17)
    kp[0, :, 1] = 40
    kp[0, :, 2] = 2
    kp[0, 5, :2] = (55, 20)   # left shoulder
    image[20, 55] = 255       # a marker on it
    depth = np.linspace(0.9, 1.1, 17)[None]
    for seed in range(20):
        crop, k, d = random_crop_flip(image, kp, depth, AugmentConfig(input_size=80, flip=0.5),
                                      np.random.default_rng(seed))
        assert crop.shape == (80, 80, 3)
        y, x = np.unravel_index(np.argmax(crop[:, :, 0]), crop.shape[:2])
        flipped = d[0, 5] != depth[0, 5]
        j = 6 if flipped else 5               # after a flip the marker is the *right* shoulder
        assert abs(k[0, j, 0] - x) <= 1.0 and abs(k[0, j, 1] - y) <= 1.0
        if flipped:
            np.testing.assert_allclose(d[0], depth[0, FLIP_PERMUTATION])


def test_sampler_mixes_data_sets_from_their_start_step():
    s = MixtureSampler([10, 5], [1.0, 1.0], [0, 3], batch_size=2, seed=0)
    it = iter(s)
    keys = [next(it) for _ in range(200)]
    assert all(k == 0 for k, _, _ in keys[:6])                    # steps 0-2: first set only
    assert {k for k, _, _ in keys[6:]} == {0, 1}
    assert all(0 <= i < (10, 5)[k] for k, i, _ in keys)
    resumed = iter(MixtureSampler([10, 5], [1.0, 1.0], [0, 3], batch_size=2, seed=0, start=50))
    assert [next(resumed) for _ in range(5)] == keys[50:55]


def test_ema_follows_parameters():
    m = torch.nn.Linear(2, 1)
    ema = EMA(m, decay=0.1)
    with torch.no_grad():
        m.weight.fill_(1.0)
    for _ in range(100):
        ema.update(m)
    assert torch.allclose(ema.state["weight"], torch.ones(1, 2), atol=1e-4)


def test_train_checkpoints_resume_and_predict(tiny_data, tmp_path):
    out = tmp_path / "run"
    path = train(_config(tiny_data, out))
    assert path.name == "checkpoint-0000003.pt"
    assert (out / "checkpoint-0000002.pt").is_file() and (out / "checkpoint-0000002.json").is_file()
    meta = json.loads(path.with_suffix(".json").read_text())
    assert meta["step"] == 3 and meta["model"] == {"backbone": "resnet18", "stride": 16, "width": 8, "upsample": 1}
    assert meta["images_per_second"] > 0 and set(meta["losses"]) >= {"L_PIF", "L_PAF", "L_PDF", "total"}
    state = torch.load(path, weights_only=True)  # tensors only: no pickled module
    assert set(state) >= {"model", "ema", "optimizer"}

    resumed = train(_config(tiny_data, out, steps=5), resume="auto")
    assert resumed.name == "checkpoint-0000005.pt"
    s5, _ = read_checkpoint(resumed)
    assert not torch.equal(s5["model"]["pif.conv.weight"], state["model"]["pif.conv.weight"])

    model, _ = load_model(resumed)
    ann = read_annotations(tiny_data)
    results = predict([ann.paths[0], ann.paths[1]], resumed, tmp_path / "pred")
    assert len(results) == 2 and results[0]["width"] == 64
    written = json.loads((tmp_path / "pred" / "predictions.json").read_text())
    assert len(written["images"]) == 2
    assert (tmp_path / "pred" / f"{ann.paths[0].stem}.overlay.jpg").is_file()


def test_bad_checkpoint_is_an_input_error(tmp_path):
    (tmp_path / "x.pt").write_bytes(b"junk")
    with pytest.raises(InputError, match="metadata not found"):
        read_checkpoint(tmp_path / "x.pt")
    (tmp_path / "x.json").write_text(json.dumps({"format": "mvm.net.checkpoint/1", "model": {}, "step": 1}))
    with pytest.raises(InputError, match="not a checkpoint"):
        read_checkpoint(tmp_path / "x.pt")


def test_dataset_items_have_the_field_shapes(tiny_data):
    ds = KeypointDataset(read_annotations(tiny_data), 8, AugmentConfig(input_size=64))
    item = ds[0]
    assert item["image"].shape == (3, 64, 64)
    assert item["pif"].shape == (17, 5, 8, 8) and item["pdf"].shape == (17, 2, 8, 8)
    assert torch.isfinite(item["pdf"][:, 0]).any()       # the synthetic data carry depth
    assert torch.equal(ds.sample(0, 7)["image"], ds.sample(0, 7)["image"])  # deterministic per draw


def test_learning_rate_warmup_and_cosine_by_hand():
    cfg = config_from_dict({"optim": {"lr": 0.5, "lr_warmup": 4, "lr_decay": "cosine", "steps": 100}})
    floor = 0.005
    assert learning_rate(cfg, 0, 0.0) == pytest.approx(floor)
    assert learning_rate(cfg, 2, 0.02) == pytest.approx(floor + (0.5 - floor) / 2)     # half-way up
    assert learning_rate(cfg, 40, 0.4) == pytest.approx(floor + (0.5 - floor) * 0.5 * (1 + np.cos(0.4 * np.pi)))
    assert learning_rate(cfg, 100, 1.0) == pytest.approx(floor)
    assert learning_rate(cfg.replace(lr_decay="none"), 90, 0.9) == 0.5
    with pytest.raises(InputError, match="lr_decay"):
        config_from_dict({"optim": {"lr_decay": "step"}})
    with pytest.raises(InputError, match="optimizer"):
        config_from_dict({"optim": {"optimizer": "rmsprop"}})


def test_time_limit_stops_training_and_adamw_trains(tiny_data, tmp_path):
    cfg = _config(tiny_data, tmp_path / "run", steps=100_000, checkpoint_every=100_000, optimizer="adamw",
                  lr_decay="cosine", max_seconds=1.0)
    t = time.perf_counter()
    path = train(cfg)
    meta = json.loads(path.with_suffix(".json").read_text())
    assert 1.0 <= meta["train_seconds"] < 60 and time.perf_counter() - t < 90
    assert 0 < meta["step"] < 100_000 and path.name == f"checkpoint-{meta['step']:07d}.pt"
    state, _ = read_checkpoint(path)
    assert "exp_avg" in state["optimizer"]["state"][0]                      # AdamW moments were kept


def _two_d_only(data, root):
    """The annotation file ``data`` without its depths: a 2D-only validation set (as COCO val2017)."""
    doc = json.loads(data.read_text())
    for ann in doc["annotations"]:
        ann.pop("keypoint_depths", None)
        ann.pop("has_3d", None)
    path = root / "val2d.json"
    path.write_text(json.dumps(doc))
    return path


def test_two_d_only_validation_trains_and_checkpoints(tiny_data, tmp_path):
    val = _two_d_only(tiny_data, tiny_data.parent)
    cfg = _config(tiny_data, tmp_path / "run", steps=4, val_every=2, checkpoint_every=100)
    cfg = cfg.replace(val=config_from_dict({"data": {"val": {"annotations": str(val)}}}).val)
    path = train(cfg)
    assert path.name == "checkpoint-0000004.pt"
    for step in (2, 4):                                                   # periodic validation
        meta = json.loads((tmp_path / "run" / f"checkpoint-{step:07d}.json").read_text())
        v = meta["validation"]
        assert v["metrics"]["depth_error"] is None and "2D-only" in v["missing"]["depth_error"]
        assert v["metrics"]["AP"] is not None and v["metrics"]["persons"] == 0.0
    records = read_metrics_log(tmp_path / "run" / "metrics.jsonl")
    assert [r["step"] for r in records if "losses" in r] == [1, 2, 3, 4]
    assert [r["step"] for r in records if "validation" in r] == [2, 4]
    assert train(cfg, resume="auto") == path                              # nothing left to do


def test_resume_after_a_kill_between_the_weights_and_the_metadata(tiny_data, tmp_path, monkeypatch):
    out = tmp_path / "run"
    train(_config(tiny_data, out, steps=2))
    import mvm.net.checkpoints as checkpoints

    real = checkpoints.atomic_write_json

    def killed(path, obj, pretty=False):
        if "0000004" in str(path):
            raise KeyboardInterrupt("killed")
        real(path, obj, pretty)

    monkeypatch.setattr(checkpoints, "atomic_write_json", killed)
    with pytest.raises(KeyboardInterrupt):
        train(_config(tiny_data, out, steps=4), resume="auto")
    monkeypatch.undo()
    assert (out / "checkpoint-0000004.pt").is_file() and not (out / "checkpoint-0000004.json").exists()
    assert latest_checkpoint(out).name == "checkpoint-0000002.pt"
    # a .json whose recorded size does not match its .pt (a .pt rewritten by a killed run) is skipped too
    meta = json.loads((out / "checkpoint-0000002.json").read_text())
    (out / "checkpoint-0000003.pt").write_bytes(b"partial")
    (out / "checkpoint-0000003.json").write_text(json.dumps(meta))
    assert latest_checkpoint(out).name == "checkpoint-0000002.pt"
    (out / "checkpoint-0000003.pt").unlink()
    (out / "checkpoint-0000003.json").unlink()
    path = train(_config(tiny_data, out, steps=4), resume="auto")
    assert path.name == "checkpoint-0000004.pt" and latest_checkpoint(out) == path
    state, meta = read_checkpoint(path)
    assert meta["step"] == 4 and meta["weights_bytes"] == path.stat().st_size


def test_keep_last_and_keep_best(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    for step, ap in zip(range(1, 6), (0.1, 0.5, 0.2, 0.3, 0.4)):
        pt = out / f"checkpoint-{step:07d}.pt"
        pt.write_bytes(b"x" * step)
        pt.with_suffix(".json").write_text(json.dumps({"format": "mvm.net.checkpoint/1", "weights_bytes": step,
                                                      "validation": {"metrics": {"AP": ap}}}))
    deleted = prune_checkpoints(out, keep_last=2, keep_best="AP")
    assert [p.name[11:18] for p in deleted] == ["0000001", "0000003"]
    assert [p.name[11:18] for p in list_checkpoints(out)] == ["0000002", "0000004", "0000005"]
    assert not (out / "checkpoint-0000001.json").exists()
    assert prune_checkpoints(out, keep_last=0) == []                      # 0: keep all
    prune_checkpoints(out, keep_last=1)
    assert [p.name for p in list_checkpoints(out)] == ["checkpoint-0000005.pt"]


def test_metadata_with_nan_is_written_as_null(tmp_path):
    assert (finite_or_none({"a": float("nan"), "b": [1.0, float("inf")], "c": "x"})
            == {"a": None, "b": [1.0, None], "c": "x"})


def test_coco_as_pifpaf_people_only_crowds_and_unlabelled_people_masked(tmp_path):
    import cv2

    from mvm.net.encoder import encode

    kp = np.zeros((17, 3))
    kp[:, 0], kp[:, 1], kp[:, 2] = np.linspace(10, 40, 17), np.linspace(10, 50, 17), 2
    doc = {"images": [{"id": i, "file_name": f"{i}.png"} for i in (1, 2, 3)],
           "annotations": [
               {"id": 1, "image_id": 1, "category_id": 1, "keypoints": kp.reshape(-1).tolist()},
               {"id": 2, "image_id": 1, "category_id": 1, "iscrowd": 1, "bbox": [70, 70, 20, 20]},
               {"id": 3, "image_id": 2, "category_id": 1, "num_keypoints": 0, "keypoints": [0] * 51,
                "bbox": [40, 0, 30, 30]}]}                                  # image 3: nobody
    (tmp_path / "a.json").write_text(json.dumps(doc))
    for i in (1, 2, 3):
        cv2.imwrite(str(tmp_path / f"{i}.png"), np.zeros((96, 96, 3), np.uint8))
    everything = read_annotations(tmp_path / "a.json")
    people = read_annotations(tmp_path / "a.json", people_only=True)
    assert len(everything.paths) == 3 and list(people.image_ids) == [1, 2]
    assert [len(k) for k in people.keypoints] == [1, 0]
    np.testing.assert_allclose(people.ignore[0], [[70, 70, 90, 90]])
    np.testing.assert_allclose(people.ignore[1], [[40, 0, 70, 30]])
    # inside the crowd box the background has no target; elsewhere it is background (0)
    t = encode(people.keypoints[0], (96, 96), 8, ignore_boxes=people.ignore[0])
    assert np.isnan(t["pif"][:, 0, 10, 10]).all() and np.isnan(t["paf"][:, 0, 10, 10]).all()
    assert (t["pif"][:, 0, 5, 10] == 0).all() and np.nanmax(t["pif"][:, 0]) == 1.0
    ds = KeypointDataset(people, 8, AugmentConfig(input_size=96, flip=0.0))
    item = ds[1]
    assert torch.isnan(item["pif"][:, 0, 1, 6]).all() and (item["pif"][:, 0, 10, 10] == 0).all()


def test_scale_augmentation_moves_keypoints_and_boxes_with_the_image():
    image = np.zeros((80, 100, 3), np.uint8)
    kp = np.zeros((1, 17, 3))
    kp[0, :, :2], kp[0, :, 2] = (50, 40), 2
    kp[0, 5, :2] = (55, 20)
    image[19:22, 54:57] = 255                                            # a marker on the left shoulder
    sides = []
    for seed in range(20):
        cfg = AugmentConfig(input_size=80, flip=0.5, scale_min=0.5, scale_max=2.0)
        crop, k, d, boxes = random_crop_flip(image, kp, np.arange(17.0)[None], cfg, np.random.default_rng(seed),
                                             np.array([[54.0, 19.0, 57.0, 22.0]]))
        if crop.max() == 0:
            continue                                                     # the marker left the crop
        y, x = np.unravel_index(np.argmax(crop[:, :, 0]), crop.shape[:2])
        j = 6 if d[0, 6] == 5 else 5                                     # after a flip: the right shoulder
        assert k[0, j, 2] > 0 and abs(k[0, j, 0] - x) <= 2.0 and abs(k[0, j, 1] - y) <= 2.0
        x0, y0, x1, y1 = boxes[0]
        assert x0 - 1 <= x <= x1 + 1 and y0 - 1 <= y <= y1 + 1
        sides.append(x1 - x0)
    assert len(sides) >= 8 and min(sides) < 0.8 * 3 and max(sides) > 1.25 * 3   # the 3 px marker shrank and grew


def test_sampler_ranks_split_one_stream():
    one = iter(MixtureSampler([10, 5], [1.0, 2.0], [0, 1], batch_size=4, seed=3, start=8))
    ranks = [iter(MixtureSampler([10, 5], [1.0, 2.0], [0, 1], batch_size=4, seed=3, start=8, rank=r, world=2))
             for r in range(2)]
    stream = [next(one) for _ in range(40)]
    assert [next(ranks[i % 2]) for i in range(40)] == stream


def _ddp_worker(rank, world, port, cfg):
    import os

    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), WORLD_SIZE=str(world), RANK=str(rank),
                      LOCAL_RANK=str(rank))
    train(cfg)


@pytest.mark.slow
def test_data_parallel_on_cpu_with_gloo(tiny_data, tmp_path):
    """Two processes (torchrun's environment, the gloo backend): one run, written once by rank 0."""
    import socket

    import torch.multiprocessing as mp

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cfg = _config(tiny_data, tmp_path / "run", steps=2).replace(threads=1)
    mp.spawn(_ddp_worker, args=(2, port, cfg), nprocs=2, join=True)
    meta = json.loads((tmp_path / "run" / "checkpoint-0000002.json").read_text())
    assert meta["step"] == 2 and meta["images_per_second"] > 0
    records = read_metrics_log(tmp_path / "run" / "metrics.jsonl")
    assert [r["step"] for r in records] == [1, 2]                         # one log, not one per process


def test_plot_draws_the_curves(tiny_data, tmp_path):
    from click.testing import CliRunner

    from mvm.cli.net import train_cmd
    from mvm.net.curves import curves

    val = _two_d_only(tiny_data, tiny_data.parent)
    out = tmp_path / "run"
    config = tmp_path / "c.toml"
    config.write_text(f"""[model]\nbackbone = "resnet18"\nstride = 16\nwidth = 8\n[data]\ninput_size = 64
[[data.train]]\nannotations = "{tiny_data}"\n[data.val]\nannotations = "{val}"
[optim]\nsteps = 2\nbatch_size = 2\nlr = 0.01
[output]\nout_dir = "{out}"\nval_every = 1\nlog_every = 1\nthreads = 1\n""")
    result = CliRunner().invoke(train_cmd, [str(config), "--device", "cpu"])
    assert result.exit_code == 0, result.output
    assert "depth_error: missing (no person with depth" in result.output
    data = curves(read_metrics_log(out / "metrics.jsonl"))
    assert data["total"][0] == [1, 2] and data["val/AP"][0] == [1, 2] and "val/depth_error" not in data
    result = CliRunner().invoke(train_cmd, [str(config), "--plot"])
    assert result.exit_code == 0, result.output
    assert (out / "curves.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("override, message", [
    ({"seed": -1}, "--set: seed: must be >= 0, got -1"),
    ({"lr": float("nan")}, "--set: lr: expected float, got nan"),
    ({"lr": 0}, "--set: lr: must be > 0, got 0.0"),
    ({"steps": "abc"}, "--set: steps: expected int, got 'abc'"),
    ({"input_size": 0}, "--set: input_size: must be >= 16, got 0"),
    ({"stride": 32}, "--set: stride: expected one of 8, 16, got 32"),
    ({"flip": 1.5}, "--set: flip: must be <= 1, got 1.5"),
])
def test_bad_training_setting_names_its_source(override, message):
    with pytest.raises(InputError) as e:
        load_config(REPO / "configs" / "train_cpu_tiny.toml", override)
    assert str(e.value) == message


@pytest.mark.parametrize("section, values, message", [
    ("optim", {"steps": "ten"}, "c.toml: steps: expected int, got 'ten'"),                   # wrong type
    ("optim", {"lr": True}, "c.toml: lr: expected float, got True"),
    ("output", {"device": 1}, "c.toml: device: expected str, got 1"),
    ("optim", {"ema_decay": 1.5}, "c.toml: ema_decay: must be <= 1, got 1.5"),                # out of range
    ("optim", {"batch_size": 0}, "c.toml: batch_size: must be >= 1, got 0"),
    ("optim", {"lr_decay": "step"}, "c.toml: lr_decay: expected one of 'none', 'cosine', got 'step'"),
    ("data", {"input_size": 0}, "c.toml: input_size: must be >= 16, got 0"),
    ("data", {"crop_min": 0.9, "crop_max": 0.8}, "c.toml: crop_min: must be <= crop_max (0.8), got 0.9"),
    ("data", {"train": [{"annotations": "a.json", "scale_min": 0}]},
     "c.toml: train[0].scale_min: must be > 0, got 0.0"),
    ("data", {"train": [{"annotations": "a.json", "weight": "heavy"}]},
     "c.toml: train[0].weight: expected float, got 'heavy'"),
    ("data", {"train": [{"images": "x"}]}, "c.toml: train[0]: expected a table with 'annotations'"),
    ("data", {"val": {"annotations": "a.json", "colour": 1}},
     "c.toml: val.colour: unknown setting (known: annotations, images, people_only, scale_max, scale_min, "
     "start_step, use_depth, weight)"),
])
def test_bad_training_setting_in_a_file_is_one_line_naming_it(section, values, message):
    with pytest.raises(InputError) as e:
        config_from_dict({section: values}, "c.toml")
    assert str(e.value) == message


def test_out_dir_naming_a_file_is_refused(tmp_path):
    (tmp_path / "run").write_text("not a directory")
    with pytest.raises(InputError) as e:
        config_from_dict({"output": {"out_dir": str(tmp_path / "run")}}, "c.toml")
    assert str(e.value) == f"c.toml: out_dir: {tmp_path / 'run'} is a file, expected a directory"
    assert config_from_dict({"output": {"out_dir": str(tmp_path)}}).out_dir == str(tmp_path)   # a directory is fine


def test_training_settings_are_checked_when_built_in_python_too():
    from mvm.net.train_config import DataSource, TrainConfig

    with pytest.raises(InputError, match="^input_size: must be >= 16, got 0$"):
        TrainConfig(input_size=0)
    with pytest.raises(InputError, match="^momentum: must be < 1, got 1.0$"):
        TrainConfig().replace(momentum=1.0)
    with pytest.raises(InputError, match=r"^train: expected a list of tables"):
        TrainConfig(train=("a.json",))
    with pytest.raises(InputError, match="^scale_min: must be <= scale_max"):
        DataSource("a.json", scale_min=2.0)
    cfg = config_from_dict({"optim": {"lr": 1, "steps": 10.0}})              # TOML numbers as the fields' types
    assert cfg.lr == 1.0 and isinstance(cfg.lr, float) and cfg.steps == 10 and isinstance(cfg.steps, int)


def _checkpoint_pair(tmp_path, state):
    pt = tmp_path / "c.pt"
    torch.save(state, pt)
    pt.with_suffix(".json").write_text(json.dumps({"format": "mvm.net.checkpoint/1", "model": {}}))
    return pt


class _NotATensor:
    """A class torch refuses to unpickle with ``weights_only=True``."""


@pytest.mark.parametrize("state, message", [
    ({"model": 5}, "model: not a checkpoint: expected a state dict (names to tensors), got int"),
    ({"model": {"w": torch.zeros(2)}, "ema": {"w": [1.0, 2.0]}},
     "ema: not a checkpoint: expected a state dict (names to tensors), 'w' is list"),
    ({"ema": {}}, "not a checkpoint: expected a dict with a 'model' state dict"),
    ([torch.zeros(2)], "not a checkpoint: expected a dict with a 'model' state dict"),
    ({"model": _NotATensor()}, "not a checkpoint: it holds objects other than tensors "
                               "(checkpoints are read as tensors only)"),
])
def test_a_checkpoint_that_is_not_a_dict_of_tensors_is_one_line_naming_it(tmp_path, state, message):
    pt = _checkpoint_pair(tmp_path, state)
    with pytest.raises(InputError) as e:
        read_checkpoint(pt)
    assert str(e.value) == f"{pt}: {message}" and "\n" not in str(e.value)
    assert "weights_only" not in str(e.value)


def test_a_damaged_checkpoint_is_one_line_naming_it(tmp_path):
    pt = _checkpoint_pair(tmp_path, {"model": {"w": torch.zeros(1000)}})
    assert read_checkpoint(pt)[0]["model"]["w"].shape == (1000,)            # the intact file reads
    data = pt.read_bytes()
    for damaged in (data[: len(data) // 2], b"", b"junk"):
        pt.write_bytes(damaged)
        with pytest.raises(InputError) as e:
            read_checkpoint(pt)
        assert str(e.value) == f"{pt}: not a checkpoint: not a torch file, or truncated"
