"""Training: the loop of SGD steps, the moving average, validation, checkpoints and resume.

The recipe of the paper (Section 5): SGD with learning rate 1e-3, momentum 0.95, batch 8,
no weight decay; an exponential moving average of the weights (decay 1e-3) for validation;
square crops of 95–100 % of the short edge, horizontal flips; 2D-only data (COCO keypoints)
mixed with MVM supervision. The settings are a :class:`mvm.net.train_config.TrainConfig`;
the data mixture is :mod:`mvm.net.sampling`, checkpoints :mod:`mvm.net.checkpoints`, the
metrics log :mod:`mvm.net.metrics_log`.
"""
from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import numpy as np
import torch

from mvm.errors import InputError
from mvm.net.checkpoints import checkpoint_paths, latest_checkpoint, prune_checkpoints, read_checkpoint, save_checkpoint
from mvm.net.distributed import Distributed, select_device, unwrap
from mvm.net.ema import EMA
from mvm.net.losses import LossWeights, total_loss
from mvm.net.metrics_log import MetricsLog
from mvm.net.model import ModelSpec, PoseNet
from mvm.net.sampling import training_loader
from mvm.net.train_config import TrainConfig

LOG = logging.getLogger(__name__)


def train(config: TrainConfig, resume: str | Path | None = None, progress=None) -> Path:
    """Train the network; returns the last checkpoint's ``.pt``.

    Args:
        config: the run's settings.
        resume: a checkpoint ``.pt`` to continue from, ``"auto"`` for the latest complete one
            in ``config.out_dir`` (a fresh start when there is none), or None.
        progress: optional callback ``progress(step, steps, losses)`` after every step: the
            steps done, the run's ``steps``, and the mean losses (a dict) every ``log_every``
            steps and at the last one, else None.

    Under ``torchrun`` (``WORLD_SIZE`` > 1) every process trains a replica
    (DistributedDataParallel, ``batch_size`` images each); only rank 0 writes.
    """
    threads = torch.get_num_threads()
    if config.threads:
        torch.set_num_threads(config.threads)
    dist = Distributed.from_environment(config.device)
    try:
        run = _train(config, resume, progress, dist)
        dist.wait_for_all()
        return run
    finally:
        dist.close()
        torch.set_num_threads(threads)


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
        model = torch.nn.parallel.DistributedDataParallel(
            model, device_ids=[device.index] if device.type == "cuda" else None)
    loader = training_loader(cfg, step, dist.rank, dist.world)
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
            mean = None
            if step % cfg.log_every == 0 or last:
                mean = clock.flush()
                _log_losses(log, step, cfg, mean, clock.rate(), optimizer)
            if progress is not None:
                progress(step, cfg.steps, mean)
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
    try:
        spec = ModelSpec.from_dict(meta["model"])
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(Path(path).with_suffix(".json"), "model", f"not a valid model spec: {e}") from None
    if spec != cfg.model_spec:
        raise InputError(path, "model", f"checkpoint is {meta['model']}, config asks for {cfg.model_spec}")


def _restore(resume, cfg: TrainConfig, model: PoseNet, optimizer, ema: EMA, device) -> tuple[int, Path | None]:
    """Load a checkpoint's weights, optimizer and moving average; returns its step and path (0, None: none)."""
    if resume == "auto":
        resume = latest_checkpoint(cfg.out_dir)
    if not resume:
        return 0, None
    state, meta = read_checkpoint(resume)
    _check_spec(resume, meta, cfg)
    missing = [k for k in ("ema", "optimizer") if k not in state]
    if missing or not isinstance(meta.get("step"), int):
        raise InputError(resume, missing[0] if missing else "step",
                         "missing: a run cannot resume from this checkpoint (init_checkpoint starts from its weights)")
    model.load_state_dict(state["model"])
    try:
        optimizer.load_state_dict(state["optimizer"])
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(resume, "optimizer", f"does not fit the {cfg.optimizer} optimizer: "
                                              f"{str(e).splitlines()[0] if str(e) else type(e).__name__}") from None
    ema.state = {k: v.to(device) for k, v in state["ema"].items()}
    ema.updates = int(state.get("ema_updates", torch.tensor(meta["step"])))
    LOG.info("resumed from %s at step %d", resume, meta["step"])
    return int(meta["step"]), Path(resume)


def _autocast(cfg: TrainConfig, device: torch.device):
    return torch.autocast(device.type, dtype=torch.bfloat16, enabled=cfg.precision == "bf16")


def _train_step(model, batch: dict, optimizer, ema: EMA, weights: LossWeights, cfg: TrainConfig,
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
    ema.update(unwrap(model))
    return parts


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


def _log_losses(log: MetricsLog, step: int, cfg: TrainConfig, mean: dict, rate: float, optimizer) -> None:
    LOG.info("step %d/%d  loss %.4f  (PIF %.3f  PAF %.3f  PDF %.4f)  %.1f images/s", step, cfg.steps,
             mean["total"], mean["L_PIF"], mean["L_PAF"], mean["L_PDF"], rate)
    log.write(step, {"losses": mean, "lr": optimizer.param_groups[0]["lr"], "images_per_second": rate})


def _checkpoint(out_dir: Path, step: int, model, ema: EMA, optimizer, cfg: TrainConfig, clock: _Clock,
                device, validation: dict | None) -> None:
    net = unwrap(model)
    state = {"model": net.state_dict(), "ema": ema.state, "optimizer": optimizer.state_dict(),
             "ema_updates": torch.tensor(ema.updates)}
    meta = {"model": net.spec.to_dict(), "config": cfg.to_dict(), "losses": clock.last,
            "images_per_second": clock.rate(), "train_seconds": clock.elapsed(), "device": str(device)}
    if validation is not None:
        meta["validation"] = validation
    path = save_checkpoint(out_dir, step, state, meta)
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
