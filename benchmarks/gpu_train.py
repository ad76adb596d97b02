"""Throughput, memory and a short training curve of the network on a GPU (or, tiny, on a CPU).

    python benchmarks/gpu_train.py [--device cuda] [--backbones resnet50 resnet152] [--batches 8 32]
                                   [--precision bf16] [--steps 20] [--curve-seconds 180] [--out RESULT.json]
    python benchmarks/gpu_train.py --tiny          # the same on a CPU with tiny settings (a check)

1. Training throughput (images/s: forward, loss, backward, SGD step and moving average on
   one batch kept on the device, so data loading is left out) and peak GPU memory, for each
   backbone and batch size at the paper's input (385 px, stride 8 fields from a stride 16
   backbone with upsampling heads) in the chosen precision.
2. A short training curve: ``mvm.net.train.train`` (the real loop: data loader workers, bf16
   autocast, metrics.jsonl, checkpoints) on synthetic renders of capsule people for
   ``--curve-seconds``, then OKS AP and depth errors of the moving average on held-out renders.

With defaults it takes about 6-8 minutes on one recent GPU (rendering the data runs on
the CPU cores meanwhile). Prints a table and writes everything as JSON to ``--out``.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch

from mvm.net.data import AugmentConfig, KeypointDataset, collate, read_annotations
from mvm.net.distributed import select_device
from mvm.net.ema import EMA
from mvm.net.losses import LossWeights, total_loss
from mvm.net.metrics_log import read_metrics_log
from mvm.net.model import ModelSpec, PoseNet
from mvm.net.train import make_optimizer, train
from mvm.net.train_config import DataSource, TrainConfig

ROOT = Path(__file__).resolve().parents[1]


def throughput(spec: ModelSpec, batch: dict, device: torch.device, precision: str, steps: int) -> dict:
    """Images per second of training steps on one resident batch, and the peak memory."""
    model = PoseNet(spec).to(device).train()
    cfg = TrainConfig(lr=1e-3, momentum=0.95)
    optimizer = make_optimizer(model, cfg)
    ema = EMA(model, 1e-3)
    batch = {k: v.to(device) for k, v in batch.items()}
    if device.type == "cuda":
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats(device)

    def step():
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16"):
            raw = model(batch["image"])
        loss, _ = total_loss({k: v.float() for k, v in raw.items()}, batch, LossWeights())
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        ema.update(model)

    def sync():
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    for _ in range(3):                                   # warm-up (cuDNN autotuning, allocator)
        step()
    sync()
    t = time.perf_counter()
    for _ in range(steps):
        step()
    sync()
    seconds = time.perf_counter() - t
    peak = torch.cuda.max_memory_allocated(device) / 2**30 if device.type == "cuda" else float("nan")
    return {"images_per_second": steps * len(batch["image"]) / seconds, "peak_memory_gib": peak,
            "step_ms": 1000 * seconds / steps}


def _render(args):
    from mvm.sim.people_images import DEMO_SCENES, synthetic_dataset

    out, n, size, seed = args
    return str(synthetic_dataset(out, n, (size, size), seed=seed, **DEMO_SCENES))


def render_parallel(root: Path, n: int, size: int, seed: int, workers: int) -> Path:
    """Render ``n`` images in ``workers`` processes (one data set per process, merged)."""
    from mvm.net.supervision import merge_datasets

    per = max(1, -(-n // workers))
    jobs = [(root / f"part{k}", min(per, n - k * per), size, seed + 7919 * k) for k in range(workers) if k * per < n]
    with ProcessPoolExecutor(len(jobs)) as pool:
        parts = list(pool.map(_render, jobs))
    return merge_datasets(parts, root / "annotations.json")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="auto")
    parser.add_argument("--tiny", action="store_true", help="tiny settings that run on a CPU in a minute or two")
    parser.add_argument("--backbones", nargs="+", default=["resnet50", "resnet152"])
    parser.add_argument("--batches", nargs="+", type=int, default=[8, 32])
    parser.add_argument("--precision", choices=["bf16", "fp32"], default="bf16")
    parser.add_argument("--input-size", type=int, default=385)
    parser.add_argument("--steps", type=int, default=20, help="timed steps per configuration")
    parser.add_argument("--curve-seconds", type=float, default=180.0, help="training time of the curve")
    parser.add_argument("--curve-backbone", default="resnet50")
    parser.add_argument("--curve-size", type=int, default=193, help="input of the curve's renders [px]")
    parser.add_argument("--train-images", type=int, default=3000)
    parser.add_argument("--val-images", type=int, default=100)
    parser.add_argument("--workers", type=int, default=min(8, os.cpu_count() or 1))
    parser.add_argument("--out", default=None, help="write the results as JSON here")
    parser.add_argument("--work", default=None, help="directory for renders and checkpoints (default: temporary)")
    args = parser.parse_args()
    if args.tiny:
        args.backbones, args.batches, args.input_size, args.steps = ["resnet18"], [2], 64, 2
        args.curve_seconds, args.curve_backbone, args.curve_size = 20.0, "resnet18", 64
        args.train_images, args.val_images, args.workers = 40, 8, 2
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    device = select_device(args.device)
    if device.type == "cuda":
        torch.backends.cudnn.benchmark = True
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"
    print(f"device: {name}, torch {torch.__version__}, precision {args.precision}")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work) if args.work else Path(tmp)
        result = {"device": name, "torch": torch.__version__, "precision": args.precision,
                  "input_size": args.input_size, "throughput": [], "curve": None}
        t = time.perf_counter()
        probe = render_parallel(work / "probe", max(args.batches), args.input_size, 11, min(args.workers, 4))
        width = 8 if args.tiny else 64
        for backbone in args.backbones:
            spec = ModelSpec(backbone, 8, width, upsample=2)
            for b in args.batches:
                ds = KeypointDataset(read_annotations(probe), spec.stride, AugmentConfig(args.input_size, flip=0.0))
                batch = collate([ds[i % len(ds)] for i in range(b)])
                try:
                    row = throughput(spec, batch, device, args.precision, args.steps)
                except torch.cuda.OutOfMemoryError:
                    row = {"images_per_second": None, "peak_memory_gib": None, "step_ms": None,
                           "error": "out of memory"}
                    torch.cuda.empty_cache()
                row.update(backbone=backbone, batch=b)
                result["throughput"].append(row)
                ips = "-" if row["images_per_second"] is None else f"{row['images_per_second']:8.1f}"
                mem = "-" if row["peak_memory_gib"] is None else f"{row['peak_memory_gib']:6.2f}"
                print(f"{backbone:10s} batch {b:3d}: {ips} images/s  peak {mem} GiB  "
                      f"({row.get('step_ms') or 0:.0f} ms/step)")
        result["throughput_seconds"] = time.perf_counter() - t
        result["curve"] = curve(args, work, device)
        print(f"total {time.perf_counter() - t:.0f} s")
        if args.out:
            Path(args.out).write_text(json.dumps(result, indent=1))
            print(args.out)


def curve(args, work: Path, device: torch.device) -> dict:
    """Train on renders for ``curve_seconds``; the loss every 25 steps and the held-out result."""
    from mvm.net.evaluate import evaluate
    from mvm.net.predict import load_model

    t = time.perf_counter()
    train_set = render_parallel(work / "train", args.train_images, args.curve_size, 0, args.workers)
    val_set = render_parallel(work / "val", args.val_images, args.curve_size, 1_000_003, 1)
    render_s = time.perf_counter() - t
    cfg = TrainConfig(train=(DataSource(str(train_set)),), backbone=args.curve_backbone, stride=8, upsample=2,
                      width=8 if args.tiny else 64, input_size=args.curve_size, flip=0.0, optimizer="adamw",
                      lr=2e-3, lr_warmup=50, lr_decay="cosine", batch_size=2 if args.tiny else 32, ema_decay=0.01,
                      steps=10_000_000, max_seconds=args.curve_seconds, background_weight=0.2,
                      depth_log_scale=0.1, out_dir=str(work / "run"), checkpoint_every=10_000_000, log_every=25,
                      workers=args.workers, device=device.type, precision=args.precision,
                      threads=1 if device.type == "cpu" else 0)
    checkpoint = train(cfg)
    records = [r for r in read_metrics_log(work / "run" / "metrics.jsonl") if "losses" in r]
    model, meta = load_model(checkpoint, device=str(device))
    held_out = evaluate(model, val_set, input_size=args.curve_size)
    print(f"curve: rendered {args.train_images} + {args.val_images} images in {render_s:.0f} s; "
          f"{meta['step']} steps of {cfg.batch_size} in {meta['train_seconds']:.0f} s "
          f"({meta['images_per_second']:.0f} images/s with data loading)")
    for r in records[:: max(1, len(records) // 12)] + records[-1:]:
        print(f"  step {r['step']:6d}  loss {r['losses']['total']:.4f}  (PIF {r['losses']['L_PIF']:.3f}  "
              f"PAF {r['losses']['L_PAF']:.3f}  PDF {r['losses']['L_PDF']:.4f})")
    print(f"held-out renders: AP {held_out['AP']:.3f}  AP50 {held_out['AP50']:.3f}  depth error "
          f"{held_out['depth_error_gt2d']:.4f} (flat person {held_out['depth_error_flat']:.4f})")
    return {"render_seconds": render_s, "steps": meta["step"], "train_seconds": meta["train_seconds"],
            "images_per_second": meta["images_per_second"], "batch_size": cfg.batch_size,
            "losses": [{"step": r["step"], **r["losses"]} for r in records],
            "held_out": {k: (None if not np.isfinite(v) else v) for k, v in held_out.items()}}


if __name__ == "__main__":
    main()
