"""``mvm export | train | predict``: supervision from reconstructed scenes, and the network.

Each command is a thin call of one library function; a bad input raises
:class:`mvm.errors.InputError`, which the ``mvm`` command prints as one line (exit status 2).
"""
from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

import click

from mvm.cli.common import FOCAL, Number, OutputPath, command, progress, refuse_unused
from mvm.cli.common import parse_sets as _parse_sets
from mvm.cli.failures import each_isolated, report_failures
from mvm.errors import InputError
from mvm.io.layout import DEFAULT_OUTPUT


@command("export")
@click.argument("scenes", nargs=-1, required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("-o", "--out", "out_dir", required=True, type=OutputPath(product="a dataset directory"),
              help="Dataset directory to write (annotations.json, images/).")
@click.option("--link", type=click.Choice(["symlink", "copy", "none"]), default="symlink", show_default=True,
              help="How the frames get into the dataset.")
@click.option("--output-name", default=DEFAULT_OUTPUT, show_default=True,
              help="Directory of each scene holding poses3d.json.")
@click.option("--min-keypoints", default=3, show_default=True, type=Number(int, ge=0, le=17),
              help="Persons with fewer labelled joints in a frame get no annotation there.")
@click.option("--complete", is_flag=True,
              help="Infer the joints a person lacks from the pose prior before projecting; every "
                   "annotation then says per keypoint whether it was observed or inferred (keypoint_flags).")
@click.option("--force", is_flag=True, help="Export even if the dataset is up to date.")
def export_cmd(scenes: tuple[Path, ...], out_dir: Path, link: str, output_name: str, min_keypoints: int,
               complete: bool, force: bool) -> None:
    """Project the 3D poses of SCENES into every frame: a COCO dataset with relative depths.

    OUT/annotations.inputs.json records what the dataset was made from: a rerun with the same
    scenes, reconstructions and options keeps it."""
    from mvm.io.layout import SUPERVISION_FILE, SceneLayout
    from mvm.io.outputs import check_output_location
    from mvm.io.provenance import fingerprints, why_redo, write_record
    from mvm.io.scene_dir import check_reconstruction_fresh, read_poses3d, read_scene, scene_inputs
    from mvm.net.supervision import (
        EXPORT_STAGE,
        export_inputs,
        export_settings,
        export_supervision,
    )

    out_dir = Path(out_dir)
    check_output_location(out_dir, [p for scene in scenes for p in scene_inputs(scene, output_name)])
    inputs = export_inputs(scenes, output_name, frames=link == "copy", located=True)
    settings = export_settings(link, min_keypoints, complete, out_dir.resolve().as_posix())
    try:
        hashed = fingerprints(inputs)
    except InputError:               # an unreadable input: its scene fails on its own below
        hashed = None
    why = ("forced" if force else "an input cannot be read" if hashed is None else
           why_redo(out_dir / SUPERVISION_FILE, inputs, settings, EXPORT_STAGE, hashed=hashed))
    if why is None:
        click.echo("export: kept (up to date)", err=True)
        return

    def read(scene_dir):
        layout = SceneLayout(scene_dir, output_name)
        poses3d = layout.poses3d
        if not poses3d.is_file():
            raise InputError(poses3d, None, "not found: reconstruct the scene first (mvm reconstruct)")
        check_reconstruction_fresh(scene_dir, poses3d)
        frames = layout.frames
        return read_scene(scene_dir), read_poses3d(poses3d, root=scene_dir), (frames if frames.is_dir() else None)

    prior = None
    if complete:
        from mvm.core.prior import shipped_prior

        prior = shipped_prior()
    failed: list = []
    items = [item for _, item in each_isolated(scenes, read, failed)]
    if failed and (out_dir / SUPERVISION_FILE).exists():    # a refused run never replaces the previous data set
        click.echo(f"export: {out_dir} left as it was (a scene was refused; fix it and export again)", err=True)
        report_failures(failed, len(scenes))

    def record(annotations: Path) -> None:     # a data set that lacks a scene is redone by the next run
        if not failed and hashed is not None:
            write_record(annotations, EXPORT_STAGE, inputs, settings, hashed)

    path = export_supervision(items, out_dir, link=link, min_keypoints=min_keypoints, prior=prior, finish=record)
    from mvm.io.checks import load_json

    click.echo(f"export: made: {why}", err=True)
    data = load_json(path)
    click.echo(f"{path}: {len(data['images'])} images, {len(data['annotations'])} annotations "
               f"from {len(scenes) - len(failed)} scene(s)")
    report_failures(failed, len(scenes))


@command("train")
@click.argument("config", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a setting, e.g. --set steps=1000 --set backbone=resnet18 (repeatable).")
@click.option("--resume", default=None, metavar="PATH|auto",
              help="Continue from a checkpoint .pt, or 'auto' for the latest complete one in out_dir.")
@click.option("--device", type=click.Choice(["auto", "cpu", "cuda"]), default=None,
              help="Override the configuration's device.")
@click.option("--plot", is_flag=True, help="Only draw the curves of out_dir/metrics.jsonl into out_dir/curves.png.")
def train_cmd(config: Path, sets: tuple[str, ...], resume: str | None, device: str | None, plot: bool) -> None:
    """Train the monocular 3D pose network with the settings of CONFIG (TOML).

    Several GPUs: torchrun --nproc-per-node N -m mvm train CONFIG (batch_size per GPU).
    """
    from mvm.net.train import train
    from mvm.net.train_config import TrainConfig, load_config

    pairs = _parse_sets(sets)
    refuse_unused(pairs, TrainConfig)
    cfg = load_config(config, pairs | ({"device": device} if device else {}))
    _check_train_output(cfg, config, resume)
    if plot:
        from mvm.net.curves import plot_metrics

        click.echo(f"{plot_metrics(Path(cfg.out_dir) / 'metrics.jsonl', Path(cfg.out_dir) / 'curves.png')}")
        return
    with train_progress() as update:
        path = train(cfg, resume=resume, progress=update)
    from mvm.io.checks import load_json_object

    meta = load_json_object(path.with_suffix(".json"))
    click.echo(f"{path}: step {meta['step']}, {meta.get('images_per_second', float('nan')):.1f} images/s "
               f"on {meta.get('device', '?')}")
    validation = meta.get("validation")
    if validation:
        shown = {k: v for k, v in validation["metrics"].items() if k in ("AP", "AP50", "depth_error")}
        click.echo("validation: " + ", ".join(f"{k} {'-' if v is None else f'{v:.4f}'}" for k, v in shown.items()))
        for name, reason in validation["missing"].items():
            click.echo(f"  {name}: missing ({reason})")


@contextmanager
def train_progress():
    """A bar of training steps with the last logged loss; yields ``update(step, steps, losses)``."""
    from rich.progress import TextColumn

    with progress(TextColumn("{task.fields[loss]}")) as bar:
        task = bar.add_task("training steps", total=None, loss="")

        def update(step: int, steps: int, losses: dict | None) -> None:
            fields = {"loss": f"loss {losses['total']:.4g}"} if losses and "total" in losses else {}
            bar.update(task, completed=step, total=steps, **fields)

        yield update


def _check_train_output(cfg, config: Path, resume: str | None) -> None:
    """``out_dir`` (checkpoints are added there, not replaced) must not be, hold or lie inside
    what the run reads: the configuration, the data sets, the initial weights, the resumed
    checkpoint."""
    from mvm.io.outputs import check_output_location

    inputs = [config, *(p for p in (cfg.pretrained, cfg.init_checkpoint) if p)]
    for source in (*cfg.train, *((cfg.val,) if cfg.val else ())):
        annotations = Path(source.annotations)
        inputs += [annotations, Path(source.images) if source.images else annotations.parent]
    if resume and resume != "auto":
        inputs.append(Path(resume))
    check_output_location(cfg.out_dir, inputs, replaced=False)


@command("predict")
@click.argument("images", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--checkpoint", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="A checkpoint .pt written by mvm train (its .json beside it).")
@click.option("-o", "--out", "out_dir", default="predictions", show_default=True,
              type=OutputPath(product="a folder (predictions.json and overlays)"),
              help="Where predictions.json and the overlays go.")
@click.option("--focal", "focal_px", default=None, type=FOCAL, help="Focal length in pixels (default: the long edge).")
@click.option("--input-size", default=None, type=Number(int, ge=16, le=4096),   # mvm.net.predict.MAX_INPUT_SIZE
              help="Long edge of the network input, 16 to 4096 px (default: as trained).")
@click.option("--device", type=click.Choice(["auto", "cpu", "cuda"]), default="auto", show_default=True,
              help="Where the network runs (auto: a GPU when there is one).")
def predict_cmd(images: tuple[Path, ...], checkpoint: Path, out_dir: Path, focal_px: float | None,
                input_size: int | None, device: str) -> None:
    """Multi-person 2D poses, relative depths and calibrated 3D poses of IMAGES."""
    from mvm.net.predict import predict

    out_dir = Path(out_dir)
    results = predict(list(images), checkpoint, out_dir, input_size=input_size, focal_px=focal_px, device=device)
    for r in results:
        click.echo(f"{r['image']}: {len(r['persons'])} people")
    click.echo(f"{out_dir / 'predictions.json'}")
