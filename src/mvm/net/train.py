"""Training: SGD, an exponential moving average of the weights, checkpoints and resume.

The recipe of the paper (Section 5): SGD with learning rate 1e-3, momentum 0.95, batch 8,
no weight decay; an exponential moving average of the weights (decay 1e-3) for validation;
square crops of 95–100 % of the short edge, horizontal flips; 2D-only data (COCO keypoints)
mixed with MVM supervision. A data set may join the mixture at ``start_step`` (COCO
pretraining first, then the Mannequin data).

A checkpoint is two files: ``checkpoint-NNNNNNN.pt`` (``{"model", "ema", "optimizer"}``
state dicts, tensors only) and ``checkpoint-NNNNNNN.json`` (metadata: model spec, step,
configuration, losses, validation, throughput). No module is pickled.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
import torch

from mvm.errors import InputError
from mvm.io.checks import load_json_object, load_toml
from mvm.io.files import atomic_write_bytes, atomic_write_json
from mvm.net.data import AugmentConfig, KeypointDataset, collate, read_annotations
from mvm.net.encoder import EncoderConfig
from mvm.net.losses import LossWeights, total_loss
from mvm.net.model import ModelSpec, PoseNet

LOG = logging.getLogger(__name__)
CHECKPOINT_FORMAT = "mvm.net.checkpoint/1"


@dataclass(frozen=True)
class DataSource:
    """One data set of the mixture.

    Attributes:
        annotations: COCO keypoints file (with or without ``keypoint_depths``).
        images: directory of the images (default: the annotation file's directory).
        weight: relative sampling weight while active. [1]
        start_step: the step from which the set is sampled (0: from the start). [steps]
        use_depth: read ``keypoint_depths`` when present (false: train it as 2D-only).
    """

    annotations: str
    images: str | None = None
    weight: float = 1.0
    start_step: int = 0
    use_depth: bool = True


@dataclass(frozen=True)
class TrainConfig:
    """Every setting of a training run (read from TOML, see ``configs/``).

    Attributes:
        backbone, stride, width: the network (see :class:`ModelSpec`).
        pretrained: torchvision ImageNet state dict of the backbone ('' for none).
        init_checkpoint: start from this checkpoint's (EMA) weights ('' for none).
        train: the data sets of the mixture; val: an optional validation set.
        input_size, crop_min, crop_max, flip: augmentation (see :class:`AugmentConfig`).
        optimizer: 'sgd' (the paper's) or 'adamw' (faster from scratch on small networks).
        lr, momentum, batch_size, weight_decay: the optimizer (momentum: SGD only).
        lr_warmup: steps of linear warm-up of the learning rate from lr / 100. [steps]
        lr_decay: 'none' (constant) or 'cosine' (to lr / 100 at the end of the run; the end is
            ``steps`` or ``max_seconds``, whichever is reached first).
        clip_grad_norm: rescale the gradient to at most this norm before each step (0: never).
        max_seconds: stop training after this many seconds even before ``steps`` (0: no limit). [s]
        ema_decay: weight of the current parameters in the moving average per step.
        steps: optimization steps of the run.
        lambda_pif, lambda_paf, lambda_pdf: λ1, λ2, λ3 of the loss.
        background_weight: weight of background cells in the confidence losses (lower: the
            few positive cells count more; faster to learn, confidences less calibrated).
        depth_log_scale: unit of the log-depth residuals in the depth loss (1: the paper's
            variance as written; about 0.1, the spread of relative log depths, balances it
            against the other terms).
        out_dir: where checkpoints go; checkpoint_every: steps between checkpoints.
        log_every: steps between log lines; workers: data-loading processes;
        device: 'auto', 'cpu' or 'cuda'; seed: random seed; threads: CPU threads of torch during
            the run (0: torch's default; 1 is much faster on a CPU shared with other processes).
    """

    train: tuple[DataSource, ...] = ()
    val: DataSource | None = None
    backbone: str = "resnet50"
    stride: int = 16
    width: int = 64
    pretrained: str = ""
    init_checkpoint: str = ""
    input_size: int = 385
    crop_min: float = 0.95
    crop_max: float = 1.0
    flip: float = 0.5
    optimizer: str = "sgd"
    lr: float = 1e-3
    lr_warmup: int = 0
    lr_decay: str = "none"
    max_seconds: float = 0.0
    clip_grad_norm: float = 0.0
    momentum: float = 0.95
    batch_size: int = 8
    weight_decay: float = 0.0
    ema_decay: float = 1e-3
    steps: int = 100000
    lambda_pif: float = 1.0
    lambda_paf: float = 1.0
    lambda_pdf: float = 1.0
    background_weight: float = 1.0
    depth_log_scale: float = 1.0
    out_dir: str = "runs/mvm-net"
    checkpoint_every: int = 5000
    log_every: int = 50
    workers: int = 0
    device: str = "auto"
    seed: int = 0
    threads: int = 0

    @property
    def model_spec(self) -> ModelSpec:
        return ModelSpec(self.backbone, self.stride, self.width)

    @property
    def augment(self) -> AugmentConfig:
        return AugmentConfig(self.input_size, self.crop_min, self.crop_max, self.flip)

    def replace(self, **changes) -> "TrainConfig":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


_SECTIONS = ("model", "data", "optim", "loss", "output")


def config_from_dict(doc: dict, source: str = "config") -> TrainConfig:
    """Build a :class:`TrainConfig` from a TOML document (sections are flattened)."""
    flat: dict = {}
    for key, value in doc.items():
        if key in _SECTIONS and isinstance(value, dict):
            flat.update(value)
        else:
            flat[key] = value
    known = {f.name: f for f in dataclasses.fields(TrainConfig)}
    unknown = sorted(set(flat) - set(known))
    if unknown:
        raise InputError(source, unknown[0], f"unknown setting (known: {', '.join(sorted(known))})")
    if "train" in flat:
        if not isinstance(flat["train"], list):
            raise InputError(source, "train", "expected a list of tables ([[data.train]])")
        flat["train"] = tuple(_source(d, source, f"train[{i}]") for i, d in enumerate(flat["train"]))
    if flat.get("val") is not None:
        flat["val"] = _source(flat["val"], source, "val")
    for name, value in flat.items():
        f = known[name]
        if f.type in ("int", "float") and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise InputError(source, name, f"expected a number, got {value!r}")
        if f.type == "int" and not isinstance(value, int):
            raise InputError(source, name, f"expected an integer, got {value!r}")
        if f.type == "str" and not isinstance(value, str):
            raise InputError(source, name, f"expected a string, got {value!r}")
    cfg = TrainConfig(**flat)
    _check(cfg, source)
    return cfg


def _source(d, source: str, field_name: str) -> DataSource:
    if not isinstance(d, dict) or "annotations" not in d:
        raise InputError(source, field_name, "expected a table with 'annotations'")
    names = {f.name for f in dataclasses.fields(DataSource)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise InputError(source, f"{field_name}.{unknown[0]}", f"unknown key (known: {', '.join(sorted(names))})")
    return DataSource(**d)


def _check(cfg: TrainConfig, source: str) -> None:
    if cfg.stride not in (8, 16):
        raise InputError(source, "stride", f"expected 8 or 16, got {cfg.stride}")
    if not 0 < cfg.crop_min <= cfg.crop_max <= 1:
        raise InputError(source, "crop_min", "expected 0 < crop_min <= crop_max <= 1")
    if not 0 < cfg.ema_decay <= 1:
        raise InputError(source, "ema_decay", f"expected a value in (0, 1], got {cfg.ema_decay}")
    if cfg.batch_size < 1 or cfg.steps < 1:
        raise InputError(source, "batch_size", "batch_size and steps must be positive")
    if cfg.optimizer not in ("sgd", "adamw"):
        raise InputError(source, "optimizer", f"expected sgd or adamw, got {cfg.optimizer!r}")
    if cfg.lr_decay not in ("none", "cosine"):
        raise InputError(source, "lr_decay", f"expected none or cosine, got {cfg.lr_decay!r}")
    if cfg.depth_log_scale <= 0:
        raise InputError(source, "depth_log_scale", f"expected a positive number, got {cfg.depth_log_scale}")
    if cfg.lr <= 0 or cfg.lr_warmup < 0 or cfg.max_seconds < 0 or cfg.clip_grad_norm < 0:
        raise InputError(source, "lr", "lr must be positive; lr_warmup, max_seconds, clip_grad_norm not negative")
    if cfg.device not in ("auto", "cpu", "cuda"):
        raise InputError(source, "device", f"expected auto, cpu or cuda, got {cfg.device!r}")


def load_config(path: str | Path, overrides: dict | None = None) -> TrainConfig:
    """Read a TOML training configuration; ``overrides`` (flat keys) replace its values."""
    path = Path(path)
    doc = load_toml(path)
    doc.update(overrides or {})
    return config_from_dict(doc, str(path))


class MixtureSampler(torch.utils.data.Sampler):
    """Infinite stream of ``(dataset, item, draw)`` keys, drawing data sets by weight.

    A data set is drawn only from its ``start_step`` on (``step = sample // batch_size``).
    Deterministic given ``seed``; ``start`` skips the samples of a resumed run.
    """

    def __init__(self, sizes, weights, start_steps, batch_size: int, seed: int, start: int = 0):
        self.sizes, self.weights = list(sizes), np.asarray(weights, dtype=float)
        self.start_steps, self.batch_size, self.seed, self.start = list(start_steps), batch_size, seed, start

    def __iter__(self) -> Iterator[tuple[int, int, int]]:
        n = self.start
        while True:
            rng = np.random.default_rng([self.seed, n])
            step = n // self.batch_size
            w = np.where((np.array(self.start_steps) <= step) & (np.array(self.sizes) > 0), self.weights, 0.0)
            if w.sum() <= 0:
                w = np.where(np.array(self.sizes) > 0, 1.0, 0.0)
            k = int(rng.choice(len(w), p=w / w.sum()))
            yield k, int(rng.integers(self.sizes[k])), n
            n += 1


class MixtureDataset(torch.utils.data.Dataset):
    """Index with ``(dataset, item, draw)``: a fresh augmentation per draw."""

    def __init__(self, datasets: list[KeypointDataset]):
        self.datasets = datasets

    def __len__(self) -> int:
        return sum(len(d) for d in self.datasets)

    def __getitem__(self, key):
        k, i, draw = key
        return self.datasets[k].sample(i, draw)


class EMA:
    """Exponential moving average of a model's parameters; buffers are copied.

    ``update`` uses ``max(decay, 1 / (updates + 1))`` so the first steps average uniformly.
    """

    def __init__(self, model: torch.nn.Module, decay: float):
        self.decay, self.updates = decay, 0
        self.state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        self.param_names = {k for k, _ in model.named_parameters()}

    @torch.no_grad()
    def update(self, model: torch.nn.Module) -> None:
        self.updates += 1
        rate = max(self.decay, 1.0 / (self.updates + 1))
        for k, v in model.state_dict().items():
            if k in self.param_names and v.dtype.is_floating_point:
                self.state[k].lerp_(v.detach(), rate)
            else:
                self.state[k].copy_(v)


def _device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise InputError(None, "device", "cuda requested but no GPU is available")
    return torch.device(name)


def checkpoint_paths(out_dir: Path, step: int) -> tuple[Path, Path]:
    stem = out_dir / f"checkpoint-{step:07d}"
    return stem.with_suffix(".pt"), stem.with_suffix(".json")


def latest_checkpoint(out_dir: str | Path) -> Path | None:
    """The ``.pt`` of the highest step in ``out_dir`` that has its JSON metadata, or None."""
    found = sorted(p for p in Path(out_dir).glob("checkpoint-*.pt") if p.with_suffix(".json").is_file())
    return found[-1] if found else None


def save_checkpoint(out_dir: Path, step: int, model: PoseNet, ema: EMA, optimizer, meta: dict) -> Path:
    """Write the state dicts and the JSON metadata atomically; returns the ``.pt`` path."""
    import io

    pt, js = checkpoint_paths(out_dir, step)
    buffer = io.BytesIO()
    torch.save({"model": model.state_dict(), "ema": ema.state, "optimizer": optimizer.state_dict(),
                "ema_updates": torch.tensor(ema.updates)}, buffer)
    atomic_write_bytes(pt, buffer.getvalue())
    atomic_write_json(js, {"format": CHECKPOINT_FORMAT, "model": model.spec.to_dict(), "step": step,
                           "torch": torch.__version__, **meta}, indent=1)
    return pt


def read_checkpoint(path: str | Path) -> tuple[dict, dict]:
    """-> (state dicts, metadata) of a checkpoint ``.pt`` and its ``.json``; InputError if unusable."""
    path = Path(path)
    js = path.with_suffix(".json")
    if not js.exists():
        raise InputError(js, None, "checkpoint metadata not found (expected beside the .pt)")
    meta = load_json_object(js, what="checkpoint metadata (an object)")
    if meta.get("format") != CHECKPOINT_FORMAT:
        raise InputError(js, "format", f"expected {CHECKPOINT_FORMAT!r}, got {meta.get('format')!r}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except Exception as e:
        raise InputError(path, None, f"not a checkpoint: {e}") from None
    if not isinstance(state, dict) or "model" not in state:
        raise InputError(path, None, "expected a dict with a 'model' state dict")
    return state, meta


def build_datasets(cfg: TrainConfig) -> MixtureDataset:
    if not cfg.train:
        raise InputError(None, "train", "no training data set given ([[data.train]])")
    sets = []
    for k, src in enumerate(cfg.train):
        ann = read_annotations(src.annotations, src.images)
        if len(ann.paths) == 0:
            raise InputError(src.annotations, "images", "empty data set")
        sets.append(KeypointDataset(ann, cfg.stride, cfg.augment, EncoderConfig(), seed=cfg.seed + k,
                                    use_depth=src.use_depth))
        n3d = sum(int(np.isfinite(d).any(axis=1).sum()) for d in ann.depths)
        LOG.info("data set %s: %d images, %d persons with depth", src.annotations, len(ann.paths), n3d)
    return MixtureDataset(sets)


def train(config: TrainConfig, resume: str | Path | None = None, progress=None) -> Path:
    """Train the network; returns the last checkpoint's ``.pt``.

    Args:
        config: the run's settings.
        resume: a checkpoint ``.pt`` to continue from, ``"auto"`` for the latest one in
            ``config.out_dir`` (a fresh start when there is none), or None.
        progress: optional callback ``progress(step, losses: dict)`` called every ``log_every`` steps.
    """
    threads = torch.get_num_threads()
    if config.threads:
        torch.set_num_threads(config.threads)
    try:
        return _train(config, resume, progress)
    finally:
        torch.set_num_threads(threads)


def _train(cfg: TrainConfig, resume, progress) -> Path:
    torch.manual_seed(cfg.seed)
    device = _device(cfg.device)
    out_dir = Path(cfg.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    model = PoseNet(cfg.model_spec)
    if cfg.pretrained:
        from mvm.net.backbone import load_torchvision_state_dict
        load_torchvision_state_dict(model.backbone, cfg.pretrained)
    if cfg.init_checkpoint:
        state, meta = read_checkpoint(cfg.init_checkpoint)
        if ModelSpec.from_dict(meta["model"]) != cfg.model_spec:
            raise InputError(cfg.init_checkpoint, "model", f"checkpoint is {meta['model']}, config asks for {cfg.model_spec}")
        model.load_state_dict(state.get("ema", state["model"]))
    model.to(device)
    optimizer = make_optimizer(model, cfg)
    ema = EMA(model, cfg.ema_decay)
    step = 0
    if resume == "auto":
        resume = latest_checkpoint(out_dir)
    if resume:
        state, meta = read_checkpoint(resume)
        if ModelSpec.from_dict(meta["model"]) != cfg.model_spec:
            raise InputError(resume, "model", f"checkpoint is {meta['model']}, config asks for {cfg.model_spec}")
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        ema.state = {k: v.to(device) for k, v in state["ema"].items()}
        ema.updates = int(state.get("ema_updates", torch.tensor(meta["step"])))
        step = int(meta["step"])
        LOG.info("resumed from %s at step %d", resume, step)
    if step >= cfg.steps:
        LOG.info("nothing to do: the checkpoint is at step %d of %d", step, cfg.steps)
        return Path(resume)

    data = build_datasets(cfg)
    sampler = MixtureSampler([len(d) for d in data.datasets], [s.weight for s in cfg.train],
                             [s.start_step for s in cfg.train], cfg.batch_size, cfg.seed, start=step * cfg.batch_size)
    loader = torch.utils.data.DataLoader(data, batch_size=cfg.batch_size, sampler=sampler, collate_fn=collate,
                                         num_workers=cfg.workers, persistent_workers=cfg.workers > 0)
    weights = LossWeights(cfg.lambda_pif, cfg.lambda_paf, cfg.lambda_pdf, cfg.background_weight, cfg.depth_log_scale)
    model.train()
    history, t0, seen, last = [], time.perf_counter(), 0, None
    start_step = step
    for batch in loader:
        elapsed = time.perf_counter() - t0
        progress_fraction = step / cfg.steps
        if cfg.max_seconds:
            progress_fraction = max(progress_fraction, elapsed / cfg.max_seconds)
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(cfg, step, progress_fraction)
        batch = {k: v.to(device, non_blocking=True) for k, v in batch.items()}
        raw = model(batch["image"])
        loss, parts = total_loss(raw, batch, weights)
        if not math.isfinite(parts["total"]):
            raise FloatingPointError(f"loss is {parts['total']} at step {step}: lower lr ({cfg.lr})")
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.clip_grad_norm > 0:
            torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.clip_grad_norm)
        optimizer.step()
        ema.update(model)
        step += 1
        seen += len(batch["image"])
        history.append(parts)
        out_of_time = cfg.max_seconds > 0 and time.perf_counter() - t0 >= cfg.max_seconds
        if out_of_time:
            LOG.info("time limit of %.0f s reached at step %d (%d steps this run)", cfg.max_seconds, step,
                     step - start_step)
        if step % cfg.log_every == 0 or step == cfg.steps or out_of_time:
            rate = seen / (time.perf_counter() - t0)
            mean = {k: float(np.mean([h[k] for h in history])) for k in history[0]}
            LOG.info("step %d/%d  loss %.4f  (PIF %.3f  PAF %.3f  PDF %.4f)  %.1f images/s", step, cfg.steps,
                     mean["total"], mean["L_PIF"], mean["L_PAF"], mean["L_PDF"], rate)
            if progress is not None:
                progress(step, mean)
            last, history = mean, []
        if step % cfg.checkpoint_every == 0 or step == cfg.steps or out_of_time:
            meta = {"config": cfg.to_dict(), "losses": last, "images_per_second": seen / (time.perf_counter() - t0),
                    "train_seconds": time.perf_counter() - t0, "device": str(device)}
            if cfg.val is not None and (step == cfg.steps or out_of_time):
                meta["validation"] = validate(ema.state, cfg, device)
            path = save_checkpoint(out_dir, step, model, ema, optimizer, meta)
            LOG.info("checkpoint %s", path)
        if step >= cfg.steps or out_of_time:
            break
    return checkpoint_paths(out_dir, step)[0]


def make_optimizer(model: torch.nn.Module, cfg: TrainConfig) -> torch.optim.Optimizer:
    """SGD with momentum (the paper) or AdamW, from the configuration."""
    if cfg.optimizer == "adamw":
        return torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    return torch.optim.SGD(model.parameters(), lr=cfg.lr, momentum=cfg.momentum, weight_decay=cfg.weight_decay)


def learning_rate(cfg: TrainConfig, step: int, progress: float) -> float:
    """The learning rate at ``step``, ``progress`` in [0, 1] being how far the run is.

    A linear warm-up from ``lr / 100`` over ``lr_warmup`` steps, then constant (``lr_decay =
    'none'``) or a cosine from ``lr`` down to ``lr / 100`` at ``progress = 1``.

    >>> cfg = TrainConfig(lr=1.0, lr_warmup=10, lr_decay="cosine", steps=100)
    >>> learning_rate(cfg, 0, 0.0), learning_rate(cfg, 50, 0.5), round(learning_rate(cfg, 100, 1.0), 6)
    (0.01, 0.505, 0.01)
    """
    floor = 0.01 * cfg.lr
    if step < cfg.lr_warmup:
        return floor + (cfg.lr - floor) * step / cfg.lr_warmup
    if cfg.lr_decay == "cosine":
        p = min(max(progress, 0.0), 1.0)
        return floor + (cfg.lr - floor) * 0.5 * (1.0 + math.cos(math.pi * p))
    return cfg.lr


def validate(ema_state: dict, cfg: TrainConfig, device: torch.device) -> dict:
    """OKS AP and depth errors of the EMA weights on ``cfg.val``."""
    from mvm.net.evaluate import evaluate

    model = PoseNet(cfg.model_spec)
    model.load_state_dict(ema_state)
    model.to(device).eval()
    result = evaluate(model, cfg.val.annotations, cfg.val.images, input_size=cfg.input_size)
    LOG.info("validation: %s", ", ".join(f"{k} {v:.4f}" for k, v in result.items()))
    return result
