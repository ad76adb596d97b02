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
import json
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
from mvm.net.losses import DEPTH_LOSSES, LossWeights, total_loss
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
        people_only: drop the images without any person annotation (as PifPaf does with COCO).
        scale_min, scale_max: random rescale of this set's crops (PifPaf on COCO: about 0.5-2;
            1, 1: none, the paper's MVM recipe). [1]
    """

    annotations: str
    images: str | None = None
    weight: float = 1.0
    start_step: int = 0
    use_depth: bool = True
    people_only: bool = True
    scale_min: float = 1.0
    scale_max: float = 1.0


@dataclass(frozen=True)
class TrainConfig:
    """Every setting of a training run (read from TOML, see ``configs/``).

    Attributes:
        backbone, stride, width, upsample: the network (see :class:`ModelSpec`).
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
        depth_loss: 'image' (the paper's L_PDF: one variance over all labelled locations of an
            image, which keeps who stands in front of whom) or 'person' (one variance per
            person: only each person's own depth profile).
        out_dir: where checkpoints go; checkpoint_every: steps between checkpoints.
        val_every: steps between validations of ``val`` (0: at the end only); a validation
            also writes a checkpoint. [steps]
        keep_last: checkpoints kept besides the best (0: keep all; a ResNet-152 checkpoint
            is about 700 MB).
        keep_best: validation metric whose best checkpoint is never pruned ('' for none;
            e.g. 'AP'; ``depth_error*`` metrics count lower as better).
        precision: 'fp32' or 'bf16' (autocast of the forward pass; the loss stays in fp32).
        log_every: steps between log lines; workers: data-loading processes;
        device: 'auto', 'cpu' or 'cuda'; seed: random seed; threads: CPU threads of torch during
            the run (0: torch's default; 1 is much faster on a CPU shared with other processes).
    """

    train: tuple[DataSource, ...] = ()
    val: DataSource | None = None
    backbone: str = "resnet50"
    stride: int = 16
    width: int = 64
    upsample: int = 1
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
    depth_loss: str = "image"
    out_dir: str = "runs/mvm-net"
    checkpoint_every: int = 5000
    val_every: int = 0
    keep_last: int = 0
    keep_best: str = ""
    precision: str = "fp32"
    log_every: int = 50
    workers: int = 0
    device: str = "auto"
    seed: int = 0
    threads: int = 0

    @property
    def model_spec(self) -> ModelSpec:
        return ModelSpec(self.backbone, self.stride, self.width, self.upsample)

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
    src = DataSource(**d)
    if not 0 < src.scale_min <= src.scale_max:
        raise InputError(source, f"{field_name}.scale_min", "expected 0 < scale_min <= scale_max")
    return src


def _check(cfg: TrainConfig, source: str) -> None:
    for f in dataclasses.fields(TrainConfig):                # every number here is a finite count, rate or weight
        value = getattr(cfg, f.name)
        if f.type in ("int", "float") and not (math.isfinite(value) and value >= 0):
            raise InputError(source, f.name, f"must be a finite number >= 0, got {value!r}")
    if cfg.stride not in (8, 16):
        raise InputError(source, "stride", f"expected 8 or 16, got {cfg.stride}")
    if cfg.upsample not in (1, 2):
        raise InputError(source, "upsample", f"expected 1 or 2, got {cfg.upsample}")
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
    if cfg.depth_loss not in DEPTH_LOSSES:
        raise InputError(source, "depth_loss", f"expected one of {', '.join(DEPTH_LOSSES)}, got {cfg.depth_loss!r}")
    if cfg.precision not in ("fp32", "bf16"):
        raise InputError(source, "precision", f"expected fp32 or bf16, got {cfg.precision!r}")
    if cfg.val_every < 0 or cfg.keep_last < 0 or cfg.checkpoint_every < 1 or cfg.log_every < 1:
        raise InputError(source, "val_every", "val_every, keep_last not negative; checkpoint_every, log_every positive")
    if cfg.device not in ("auto", "cpu", "cuda"):
        raise InputError(source, "device", f"expected auto, cpu or cuda, got {cfg.device!r}")


def load_config(path: str | Path, overrides: dict | None = None) -> TrainConfig:
    """Read a TOML training configuration; ``overrides`` (flat keys) replace its values."""
    path = Path(path)
    doc = load_toml(path)
    doc.update(overrides or {})
    try:
        return config_from_dict(doc, str(path))
    except InputError as e:
        if e.field in (overrides or {}):
            raise InputError("--set", e.field, e.problem) from None
        raise


class MixtureSampler(torch.utils.data.Sampler):
    """Infinite stream of ``(dataset, item, draw)`` keys, drawing data sets by weight.

    A data set is drawn only from its ``start_step`` on (``step = sample // batch_size``).
    Deterministic given ``seed``; ``start`` skips the samples of a resumed run. Process
    ``rank`` of ``world`` takes every ``world``-th sample of the one stream (``batch_size`` is
    then the global batch).
    """

    def __init__(self, sizes, weights, start_steps, batch_size: int, seed: int, start: int = 0,
                 rank: int = 0, world: int = 1):
        self.sizes, self.weights = list(sizes), np.asarray(weights, dtype=float)
        self.start_steps, self.batch_size, self.seed, self.start = list(start_steps), batch_size, seed, start
        self.rank, self.world = rank, world

    def __iter__(self) -> Iterator[tuple[int, int, int]]:
        n = self.start + self.rank
        while True:
            rng = np.random.default_rng([self.seed, n])
            step = n // self.batch_size
            w = np.where((np.array(self.start_steps) <= step) & (np.array(self.sizes) > 0), self.weights, 0.0)
            if w.sum() <= 0:
                w = np.where(np.array(self.sizes) > 0, 1.0, 0.0)
            k = int(rng.choice(len(w), p=w / w.sum()))
            yield k, int(rng.integers(self.sizes[k])), n
            n += self.world


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


def select_device(name: str, index: int = 0) -> torch.device:
    """'auto' (a GPU when there is one), 'cpu' or 'cuda' (an InputError without a GPU)."""
    if name not in ("auto", "cpu", "cuda"):
        raise InputError(None, "device", f"expected auto, cpu or cuda, got {name!r}")
    if name == "cuda" and not torch.cuda.is_available():
        raise InputError(None, "device", "cuda requested but no GPU is available")
    if name == "cpu" or not torch.cuda.is_available():
        return torch.device("cpu")
    return torch.device("cuda", index)


def checkpoint_paths(out_dir: Path, step: int) -> tuple[Path, Path]:
    stem = Path(out_dir) / f"checkpoint-{step:07d}"
    return stem.with_suffix(".pt"), stem.with_suffix(".json")


def _complete(pt: Path) -> bool:
    """Whether ``pt`` and its ``.json`` form a complete pair: the metadata parses, has the
    checkpoint format and records the byte size the ``.pt`` has."""
    try:
        meta = load_json_object(pt.with_suffix(".json"))
        return meta.get("format") == CHECKPOINT_FORMAT and meta.get("weights_bytes") in (None, pt.stat().st_size)
    except (OSError, ValueError, AttributeError):
        return False


def list_checkpoints(out_dir: str | Path) -> list[Path]:
    """The ``.pt`` of every complete checkpoint pair in ``out_dir``, by step."""
    return sorted(p for p in Path(out_dir).glob("checkpoint-*.pt") if _complete(p))


def latest_checkpoint(out_dir: str | Path) -> Path | None:
    """The ``.pt`` of the highest step in ``out_dir`` whose pair is complete, or None.

    A ``.pt`` without its ``.json`` (a run killed between the two writes), or whose ``.json``
    records another size, is skipped.
    """
    found = list_checkpoints(out_dir)
    return found[-1] if found else None


def finite_or_none(obj):
    """``obj`` with every NaN or infinite float replaced by None (JSON ``null``)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    return obj


def save_checkpoint(out_dir: Path, step: int, model: PoseNet, ema: EMA, optimizer, meta: dict) -> Path:
    """Write the state dicts, then the JSON metadata, each atomically; returns the ``.pt`` path.

    The metadata is written last and records the ``.pt``'s size, so a pair is complete only
    when both writes finished (see :func:`latest_checkpoint`). Non-finite numbers of ``meta``
    are written as null.
    """
    import io

    pt, js = checkpoint_paths(out_dir, step)
    buffer = io.BytesIO()
    torch.save({"model": _unwrap(model).state_dict(), "ema": ema.state, "optimizer": optimizer.state_dict(),
                "ema_updates": torch.tensor(ema.updates)}, buffer)
    data = buffer.getvalue()
    atomic_write_bytes(pt, data)
    atomic_write_json(js, finite_or_none({"format": CHECKPOINT_FORMAT, "model": _unwrap(model).spec.to_dict(),
                                          "step": step, "torch": torch.__version__, "weights_bytes": len(data),
                                          **meta}), pretty=True)
    return pt


def prune_checkpoints(out_dir: str | Path, keep_last: int, keep_best: str = "", higher_is_better: bool = True) -> list[Path]:
    """Delete complete checkpoint pairs beyond the ``keep_last`` most recent (0: keep all).

    With ``keep_best`` (a validation metric, e.g. ``"AP"``), the checkpoint with the best
    recorded value of it is kept too. Returns the deleted ``.pt`` paths.
    """
    found = list_checkpoints(out_dir)
    if keep_last <= 0 or len(found) <= keep_last:
        return []
    keep = set(found[-keep_last:])
    if keep_best:
        best = _best_checkpoint(found, keep_best, higher_is_better)
        if best is not None:
            keep.add(best)
    deleted = []
    for pt in found:
        if pt not in keep:
            pt.with_suffix(".json").unlink(missing_ok=True)       # the pair is incomplete from here on
            pt.unlink(missing_ok=True)
            deleted.append(pt)
    return deleted


def _best_checkpoint(found: list[Path], metric: str, higher_is_better: bool) -> Path | None:
    scored = []
    for pt in found:
        meta = load_json_object(pt.with_suffix(".json"))
        value = ((meta.get("validation") or {}).get("metrics") or {}).get(metric)
        if isinstance(value, (int, float)):
            scored.append((value if higher_is_better else -value, pt))
    return max(scored)[1] if scored else None


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
        ann = read_annotations(src.annotations, src.images, people_only=src.people_only)
        if len(ann.paths) == 0:
            raise InputError(src.annotations, "images", "empty data set (no image with a person)")
        augment = dataclasses.replace(cfg.augment, scale_min=src.scale_min, scale_max=src.scale_max)
        sets.append(KeypointDataset(ann, cfg.stride, augment, EncoderConfig(), seed=cfg.seed + k,
                                    use_depth=src.use_depth))
        n3d = sum(int(np.isfinite(d).any(axis=1).sum()) for d in ann.depths)
        LOG.info("data set %s: %d images, %d persons with depth", src.annotations, len(ann.paths), n3d)
    return MixtureDataset(sets)


def train(config: TrainConfig, resume: str | Path | None = None, progress=None) -> Path:
    """Train the network; returns the last checkpoint's ``.pt``.

    Args:
        config: the run's settings.
        resume: a checkpoint ``.pt`` to continue from, ``"auto"`` for the latest complete one
            in ``config.out_dir`` (a fresh start when there is none), or None.
        progress: optional callback ``progress(step, losses: dict)`` called every ``log_every`` steps.

    Under ``torchrun`` (``WORLD_SIZE`` > 1) every process trains a replica
    (DistributedDataParallel, ``batch_size`` images each); only rank 0 writes.
    """
    threads = torch.get_num_threads()
    if config.threads:
        torch.set_num_threads(config.threads)
    dist = Distributed.from_environment(config.device)
    try:
        return _train(config, resume, progress, dist)
    finally:
        dist.close()
        torch.set_num_threads(threads)


@dataclass
class Distributed:
    """The process group of a ``torchrun`` launch (world size 1 without one)."""

    rank: int = 0
    world: int = 1
    local_rank: int = 0

    @classmethod
    def from_environment(cls, device: str) -> "Distributed":
        import os

        world = int(os.environ.get("WORLD_SIZE", "1"))
        if world <= 1:
            return cls()
        rank, local = int(os.environ.get("RANK", "0")), int(os.environ.get("LOCAL_RANK", "0"))
        cuda = device != "cpu" and torch.cuda.is_available()
        if cuda:
            torch.cuda.set_device(local)
        torch.distributed.init_process_group("nccl" if cuda else "gloo")
        return cls(rank, world, local)

    @property
    def main(self) -> bool:
        return self.rank == 0

    def close(self) -> None:
        if self.world > 1 and torch.distributed.is_initialized():
            torch.distributed.destroy_process_group()


def _unwrap(model: torch.nn.Module) -> PoseNet:
    return model.module if isinstance(model, torch.nn.parallel.DistributedDataParallel) else model


def _build_model(cfg: TrainConfig) -> PoseNet:
    model = PoseNet(cfg.model_spec)
    if cfg.pretrained:
        from mvm.net.backbone import load_torchvision_state_dict
        load_torchvision_state_dict(model.backbone, cfg.pretrained)
    if cfg.init_checkpoint:
        state, meta = read_checkpoint(cfg.init_checkpoint)
        _check_spec(cfg.init_checkpoint, meta, cfg)
        model.load_state_dict(state.get("ema", state["model"]))
    return model


def _check_spec(path, meta: dict, cfg: TrainConfig) -> None:
    if ModelSpec.from_dict(meta["model"]) != cfg.model_spec:
        raise InputError(path, "model", f"checkpoint is {meta['model']}, config asks for {cfg.model_spec}")


def _restore(resume, cfg: TrainConfig, model: PoseNet, optimizer, ema: "EMA", device) -> tuple[int, Path | None]:
    """Load a checkpoint's weights, optimizer and moving average; returns its step and path (0, None: none)."""
    if resume == "auto":
        resume = latest_checkpoint(cfg.out_dir)
    if not resume:
        return 0, None
    state, meta = read_checkpoint(resume)
    _check_spec(resume, meta, cfg)
    model.load_state_dict(state["model"])
    optimizer.load_state_dict(state["optimizer"])
    ema.state = {k: v.to(device) for k, v in state["ema"].items()}
    ema.updates = int(state.get("ema_updates", torch.tensor(meta["step"])))
    LOG.info("resumed from %s at step %d", resume, meta["step"])
    return int(meta["step"]), Path(resume)


def _loader(cfg: TrainConfig, step: int, dist: Distributed) -> torch.utils.data.DataLoader:
    data = build_datasets(cfg)
    sampler = MixtureSampler([len(d) for d in data.datasets], [s.weight for s in cfg.train],
                             [s.start_step for s in cfg.train], cfg.batch_size * dist.world, cfg.seed,
                             start=step * cfg.batch_size * dist.world, rank=dist.rank, world=dist.world)
    return torch.utils.data.DataLoader(data, batch_size=cfg.batch_size, sampler=sampler, collate_fn=collate,
                                       num_workers=cfg.workers, persistent_workers=cfg.workers > 0,
                                       pin_memory=torch.cuda.is_available() and cfg.device != "cpu")


def _autocast(cfg: TrainConfig, device: torch.device):
    return torch.autocast(device.type, dtype=torch.bfloat16, enabled=cfg.precision == "bf16")


def _train_step(model, batch: dict, optimizer, ema: "EMA", weights: LossWeights, cfg: TrainConfig,
                device: torch.device, step: int) -> dict[str, float]:
    """One optimization step on ``batch``; returns the loss components (floats)."""
    batch = {k: v.to(device, non_blocking=True) for k, v in batch.items()}
    with _autocast(cfg, device):
        raw = model(batch["image"])
    raw = {k: v.float() for k, v in raw.items()}
    loss, parts = total_loss(raw, batch, weights)
    if not math.isfinite(parts["total"]):
        raise FloatingPointError(f"loss is {parts['total']} at step {step}: lower lr ({cfg.lr})")
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if cfg.clip_grad_norm > 0:
        torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.clip_grad_norm)
    optimizer.step()
    ema.update(_unwrap(model))
    return parts


def _train(cfg: TrainConfig, resume, progress, dist: Distributed) -> Path:
    torch.manual_seed(cfg.seed)
    device = select_device(cfg.device, dist.local_rank)
    out_dir = Path(cfg.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    model = _build_model(cfg).to(device)
    optimizer = make_optimizer(model, cfg)
    ema = EMA(model, cfg.ema_decay)
    step, resumed = _restore(resume, cfg, model, optimizer, ema, device)
    if step >= cfg.steps:
        LOG.info("nothing to do: the checkpoint is at step %d of %d", step, cfg.steps)
        return resumed
    if dist.world > 1:
        model = torch.nn.parallel.DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None)
    loader = _loader(cfg, step, dist)
    weights = LossWeights(cfg.lambda_pif, cfg.lambda_paf, cfg.lambda_pdf, cfg.background_weight,
                          cfg.depth_log_scale, cfg.depth_loss)
    log = MetricsLog(out_dir, enabled=dist.main)
    clock = _Clock(step, cfg.batch_size * dist.world)
    model.train()
    try:
        for batch in loader:
            _set_learning_rate(optimizer, cfg, step, clock.elapsed())
            parts = _train_step(model, batch, optimizer, ema, weights, cfg, device, step)
            step += 1
            clock.add(parts)
            out_of_time = cfg.max_seconds > 0 and clock.elapsed() >= cfg.max_seconds
            if out_of_time:
                LOG.info("time limit of %.0f s reached at step %d (%d steps this run)", cfg.max_seconds, step,
                         step - clock.start_step)
            last = step >= cfg.steps or out_of_time
            if step % cfg.log_every == 0 or last:
                mean = clock.flush()
                _log_losses(log, step, cfg, mean, clock.rate(), optimizer)
                if progress is not None:
                    progress(step, mean)
            validation = None
            if cfg.val is not None and dist.main and (last or (cfg.val_every and step % cfg.val_every == 0)):
                validation = validate(ema.state, cfg, device)
                log.write(step, {"validation": validation})
            if dist.main and (step % cfg.checkpoint_every == 0 or last or validation is not None):
                _checkpoint(out_dir, step, model, ema, optimizer, cfg, clock, device, validation)
            if last:
                break
    finally:
        log.close()
    return checkpoint_paths(out_dir, step)[0]


class _Clock:
    """Throughput and the losses since the last log line of a run."""

    def __init__(self, start_step: int, images_per_step: int):
        self.t0, self.start_step, self.images_per_step = time.perf_counter(), start_step, images_per_step
        self.steps, self.history, self.last = 0, [], None

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def add(self, parts: dict) -> None:
        self.steps += 1
        self.history.append(parts)

    def rate(self) -> float:
        return self.steps * self.images_per_step / max(self.elapsed(), 1e-9)

    def flush(self) -> dict[str, float]:
        if self.history:
            self.last = {k: float(np.mean([h[k] for h in self.history])) for k in self.history[0]}
            self.history = []
        return self.last


def _set_learning_rate(optimizer, cfg: TrainConfig, step: int, elapsed: float) -> None:
    fraction = step / cfg.steps
    if cfg.max_seconds:
        fraction = max(fraction, elapsed / cfg.max_seconds)
    for group in optimizer.param_groups:
        group["lr"] = learning_rate(cfg, step, fraction)


def _log_losses(log: "MetricsLog", step: int, cfg: TrainConfig, mean: dict, rate: float, optimizer) -> None:
    LOG.info("step %d/%d  loss %.4f  (PIF %.3f  PAF %.3f  PDF %.4f)  %.1f images/s", step, cfg.steps,
             mean["total"], mean["L_PIF"], mean["L_PAF"], mean["L_PDF"], rate)
    log.write(step, {"losses": mean, "lr": optimizer.param_groups[0]["lr"], "images_per_second": rate})


def _checkpoint(out_dir: Path, step: int, model, ema: "EMA", optimizer, cfg: TrainConfig, clock: _Clock,
                device, validation: dict | None) -> None:
    meta = {"config": cfg.to_dict(), "losses": clock.last, "images_per_second": clock.rate(),
            "train_seconds": clock.elapsed(), "device": str(device)}
    if validation is not None:
        meta["validation"] = validation
    path = save_checkpoint(out_dir, step, model, ema, optimizer, meta)
    LOG.info("checkpoint %s", path)
    for old in prune_checkpoints(out_dir, cfg.keep_last, cfg.keep_best, not cfg.keep_best.startswith("depth_error")):
        LOG.info("removed %s (keep_last = %d)", old, cfg.keep_last)


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
    """OKS AP and depth errors of the EMA weights on ``cfg.val``; never raises.

    Returns ``{"metrics": {name: value or None}, "missing": {name: reason}}``: a metric that
    cannot be computed (no depth in a 2D-only set, no person matched yet) is None with its
    reason; a validation set that cannot be read leaves every metric missing with the error.
    """
    from mvm.net.evaluate import evaluate, missing_reasons

    model = PoseNet(cfg.model_spec)
    model.load_state_dict(ema_state)
    model.to(device).eval()
    try:
        result = evaluate(model, cfg.val.annotations, cfg.val.images, input_size=cfg.input_size)
    except (InputError, OSError, ValueError, RuntimeError) as e:
        LOG.warning("validation failed, the run goes on: %s", e)
        return {"metrics": {}, "missing": {"*": f"{type(e).__name__}: {e}"}}
    missing = missing_reasons(result)
    metrics = {k: (None if k in missing else float(v)) for k, v in result.items()}
    LOG.info("validation: %s", ", ".join(f"{k} {'-' if v is None else format(v, '.4f')}" for k, v in metrics.items()))
    return {"metrics": metrics, "missing": missing}


class MetricsLog:
    """``metrics.jsonl`` in the run directory: one JSON object per line, ``{"step", "time", …}``
    (losses every ``log_every`` steps, validations), plus TensorBoard events under ``tb/``
    when the ``tensorboard`` package is installed. Appends, so a resumed run continues it."""

    def __init__(self, out_dir: Path, enabled: bool = True):
        self.path, self.file, self.tb = Path(out_dir) / "metrics.jsonl", None, None
        if not enabled:
            return
        self.file = self.path.open("a")
        try:
            from torch.utils.tensorboard import SummaryWriter
            self.tb = SummaryWriter(str(Path(out_dir) / "tb"))
        except ImportError:
            pass

    def write(self, step: int, record: dict) -> None:
        if self.file is None:
            return
        self.file.write(json.dumps(finite_or_none({"step": step, "time": time.time(), **record})) + "\n")
        self.file.flush()
        if self.tb is not None:
            for name, value in _scalars(record):
                self.tb.add_scalar(name, value, step)

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
        if self.tb is not None:
            self.tb.close()


def _scalars(record: dict, prefix: str = ""):
    for key, value in record.items():
        if isinstance(value, dict):
            yield from _scalars(value, f"{prefix}{key}/")
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
            yield f"{prefix}{key}", value


def read_metrics_log(path: str | Path) -> list[dict]:
    """The records of a ``metrics.jsonl``; a truncated last line (a killed run) is skipped."""
    records = []
    for line in Path(path).read_text().splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records
