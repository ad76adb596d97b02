"""Train the monocular network on a CPU for a few minutes on synthetic renders and evaluate it.

    python benchmarks/train_synthetic.py [--minutes 6] [--train-images 2000] [--val-images 100]
                                         [--seed 0] [--threads 1] [--work DIR] [--save CKPT.pt]

Renders a training set and a held-out set of capsule people with 3D supervision
(``mvm.sim.people_images.demo_datasets``), trains the small network of ``configs/train_cpu_tiny.toml``
for ``--minutes`` of wall time (the cosine learning-rate schedule follows the time budget),
and prints, on the held-out renders, OKS AP / AP50 and the relative depth errors of:

- the untrained network (the very weights training starts from),
- the trained network (the moving average of its weights),
- the flat baseline, which puts every joint of a person at the same depth.

``--save`` copies the final checkpoint (``.pt`` and its ``.json``) to the given path, for
``mvm predict``. No GPU is used even when one is present (``device = "cpu"``).
"""
from __future__ import annotations

import argparse
import logging
import shutil
import tempfile
import time
from pathlib import Path

import torch

from mvm.net.checkpoints import read_checkpoint
from mvm.net.evaluate import evaluate
from mvm.net.model import PoseNet
from mvm.net.train import train
from mvm.net.train_config import DataSource, load_config
from mvm.sim.people_images import demo_datasets

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=6.0, help="training wall time")
    parser.add_argument("--train-images", type=int, default=2000)
    parser.add_argument("--val-images", type=int, default=100)
    parser.add_argument("--config", default=str(ROOT / "configs" / "train_cpu_tiny.toml"))
    parser.add_argument("--seed", type=int, default=0, help="renders and initialization")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (1 is fastest on a busy machine)")
    parser.add_argument("--work", default=None, help="directory for renders and checkpoints (default: a temporary one)")
    parser.add_argument("--save", default=None, help="copy the final checkpoint to this .pt path")
    parser.add_argument("-v", "--verbose", action="store_true", help="log the training losses")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work) if args.work else Path(tmp)
        run(args, work)


def run(args, work: Path) -> None:
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.table import Table

    console = Console(width=max(Console().width, 100))
    base = load_config(args.config)
    t = time.perf_counter()
    train_set, val_set = demo_datasets(work / "data", args.train_images, args.val_images, base.input_size, args.seed)
    console.print(f"rendered {args.train_images} training and {args.val_images} held-out images "
                  f"({base.input_size} px) in {time.perf_counter() - t:.0f} s")
    cfg = base.replace(train=(DataSource(str(train_set)),), val=None, out_dir=str(work / "run"), steps=10_000_000,
                       max_seconds=60.0 * args.minutes, checkpoint_every=10_000_000, device="cpu", seed=args.seed,
                       threads=args.threads)
    torch.set_num_threads(args.threads)
    torch.manual_seed(cfg.seed)                      # the initialization train() starts from
    untrained = evaluate(PoseNet(cfg.model_spec), val_set, input_size=cfg.input_size)

    with Progress(TextColumn("training"), BarColumn(), TextColumn("{task.fields[info]}"), TimeElapsedColumn(),
                  console=console, transient=True) as bar:
        task = bar.add_task("train", total=cfg.max_seconds, info="")
        t0 = time.perf_counter()

        def progress(step, losses):
            bar.update(task, completed=min(time.perf_counter() - t0, cfg.max_seconds),
                       info=f"step {step}  loss {losses['total']:.3f}")

        checkpoint = train(cfg.replace(log_every=25), progress=progress)
    state, meta = read_checkpoint(checkpoint)
    model = PoseNet(cfg.model_spec)
    model.load_state_dict(state["ema"])
    trained = evaluate(model, val_set, input_size=cfg.input_size)

    table = Table(title=f"held-out renders: {args.val_images} images, {int(untrained['persons'])} people")
    for column in ("", "OKS AP", "AP50", "matched", "depth err. (detections)", "depth err. (GT 2D)"):
        table.add_column(column, justify="right")
    for name, r in (("untrained", untrained), ("trained", trained)):
        table.add_row(name, f"{r['AP']:.3f}", f"{r['AP50']:.3f}", f"{int(r['matched'])}",
                      "-" if r["matched"] == 0 else f"{r['depth_error']:.4f}", f"{r['depth_error_gt2d']:.4f}")
    table.add_row("flat depth", "", "", "", f"{trained['depth_error_flat_matched']:.4f}",
                  f"{trained['depth_error_flat']:.4f}")
    console.print(table)
    console.print(f"training: {meta['step']} steps of {cfg.batch_size} in {meta['train_seconds']:.0f} s, "
                  f"{meta['images_per_second']:.1f} images/s, {args.threads} thread(s), "
                  f"{cfg.backbone} width {cfg.width}, stride {cfg.stride}, {cfg.input_size} px")
    if args.save:
        target = Path(args.save).with_suffix(".pt")
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(checkpoint, target)
        shutil.copyfile(Path(checkpoint).with_suffix(".json"), target.with_suffix(".json"))
        console.print(f"checkpoint: {target}")


if __name__ == "__main__":
    main()
