"""``mvm evaluate 3dpw | coco | cvar``: the paper's Tables 3, 4 and 5.

Each subcommand calls one library function, prints the table row the paper prints and writes
the full result as JSON (``--out``). A bad input raises :class:`mvm.errors.InputError`, which
the ``mvm`` command prints as one line (exit status 2).
"""
from __future__ import annotations

from pathlib import Path

import click

from mvm.cli.common import Group
from mvm.io.layout import DEFAULT_OUTPUT


def _write(out: Path | None, result: dict) -> None:
    """Write ``result`` (NaN for a figure that could not be computed) as JSON (``null`` for NaN)."""
    if out is not None:
        from mvm.net.metrics_log import finite_or_none

        _write_json(out, finite_or_none(result))


def _write_json(out: Path | None, document: dict) -> None:
    """Write ``document`` (finite numbers, None where missing) as JSON."""
    if out is not None:
        from mvm.io.files import atomic_write_json

        atomic_write_json(out, document, pretty=True)
        click.echo(f"{out}")


def _number(value, scale: float = 1.0, digits: int = 1) -> str:
    return "-" if value is None or value != value else f"{scale * value:.{digits}f}"


@click.group("evaluate", cls=Group)
def evaluate() -> None:
    """The paper's evaluations: 3DPW PA-MPJPE (Table 3), COCO OKS AP (Table 4), C_var (Table 5)."""


_checkpoint = click.option("--checkpoint", required=True, type=click.Path(dir_okay=False, path_type=Path),
                           help="A checkpoint .pt written by mvm train (its .json beside it).")
_out = click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=None,
                    help="Write the full result as JSON here.")
_label = click.option("--label", default="our network", show_default=True, help="First column of the table row.")
_device = click.option("--device", type=click.Choice(["auto", "cpu", "cuda"]), default="auto", show_default=True)


def _load(checkpoint: Path, device: str, input_size: int | None):
    from mvm.net.distributed import select_device
    from mvm.net.predict import load_model

    model, meta = load_model(checkpoint, device=str(select_device(device)))
    return model, input_size or int(meta.get("config", {}).get("input_size", 385))


@evaluate.command("3dpw")
@click.argument("root", type=click.Path(file_okay=False, path_type=Path))
@_checkpoint
@click.option("--split", type=click.Choice(["test", "validation", "train"]), default="test", show_default=True)
@click.option("--min-visible", default=7, show_default=True,
              help="Ignore subjects with fewer visible 2D joints (of 14).")
@click.option("--max-images", type=int, default=None, help="Evaluate the first N images only (a quick check).")
@click.option("--input-size", type=int, default=None, help="Long edge of the network input (default: as trained).")
@_device
@_label
@_out
def threedpw_cmd(root: Path, checkpoint: Path, split: str, min_visible: int, max_images: int | None,
                 input_size: int | None, device: str, label: str, out: Path | None) -> None:
    """Table 3: PA-MPJPE on 3DPW (ROOT holds sequenceFiles/ and imageFiles/)."""
    from mvm.io.checks import check_input_file
    from mvm.net.evaluate import evaluate_3dpw
    from mvm.net.threedpw import read_3dpw

    check_input_file(checkpoint)                         # a missing checkpoint is said before the data set is read
    data = read_3dpw(root, split)
    model, size = _load(checkpoint, device, input_size)
    result = evaluate_3dpw(model, data, size, min_visible=min_visible, max_images=max_images)
    result.update(split=split, checkpoint=str(checkpoint))
    click.echo(f"{'single frame':<32} | PA-MPJPE (mm)")
    click.echo(f"{label:<32} | {_number(result['PA_MPJPE_mm'])}")
    click.echo(f"{result['images']} images, {result['poses']} poses of {result['tracks']} tracked people; "
               f"{result['missed']} not detected, {result['ignored']} with < {min_visible} visible joints")
    _write(out, result)


@evaluate.command("coco")
@click.argument("annotations", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--images", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Directory of the images (default: beside ANNOTATIONS).")
@click.option("--checkpoint", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Run this network on the images (a checkpoint .pt of mvm train).")
@click.option("--detections", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Or evaluate a COCO results file ([{image_id, keypoints, score}]).")
@click.option("--max-images", type=int, default=None, help="Evaluate the first N images only (a quick check).")
@click.option("--input-size", type=int, default=None, help="Long edge of the network input (default: as trained).")
@_device
@_label
@_out
def coco_cmd(annotations: Path, images: Path | None, checkpoint: Path | None, detections: Path | None,
             max_images: int | None, input_size: int | None, device: str, label: str, out: Path | None) -> None:
    """Table 4: OKS AP and AP50 (pycocotools) on a COCO keypoints file (e.g. person_keypoints_val2017.json)."""
    from mvm.errors import InputError
    from mvm.net.evaluate import evaluate, evaluate_detections

    if (checkpoint is None) == (detections is None):
        raise InputError(None, "--checkpoint", "give either --checkpoint or --detections")
    if detections is not None:
        result = evaluate_detections(annotations, detections)
    else:
        model, size = _load(checkpoint, device, input_size)
        result = evaluate(model, annotations, images, input_size=size, max_images=max_images)
    click.echo(f"{'':<32} | mAP@OKS | AP@OKS=0.5")
    click.echo(f"{label:<32} | {_number(result['AP'], 100):>7} | {_number(result['AP50'], 100):>10}")
    _write(out, result)


@evaluate.command("cvar")
@click.argument("scenes", nargs=-1, required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("--tau", "taus", type=float, multiple=True,
              help="Confidence threshold (repeatable; default 0.5 and 0.9).")
@click.option("--output-name", default=DEFAULT_OUTPUT, show_default=True,
              help="Directory of each scene holding poses3d.json.")
@click.option("--label", default="detector of poses2d.json", show_default=True, help="First column of the table row.")
@_out
def cvar_cmd(scenes: tuple[Path, ...], taus: tuple[float, ...], output_name: str, label: str, out: Path | None) -> None:
    """Table 5: C_var of the 2D poses of reconstructed SCENES (run on the detector's poses2d.json)."""
    from mvm.eval.cvar import evaluate_cvar

    taus = taus or (0.5, 0.9)
    result = evaluate_cvar(list(scenes), taus, output_name)
    click.echo(f"{'2D pose network':<32} | " + " | ".join(f"C_var@tau={t}" for t in taus))
    click.echo(f"{label:<32} | " + " | ".join(f"{_number(result['C_var'][str(t)], digits=4):>11}" for t in taus))
    for name in result["missing"]:
        click.echo(f"missing: {name}: {result['missing'][name]}")
    _write_json(out, result)
