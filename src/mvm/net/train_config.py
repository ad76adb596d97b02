"""The settings of a training run (:class:`TrainConfig`) and of each data set of its mixture
(:class:`DataSource`), read from TOML (see ``configs/``) and ``--set`` overrides.

Every setting has one default, one validator (:func:`mvm.core.config.setting`, checked when the
object is built: a bad value is one line naming the file or ``--set`` and the setting) and one
line of documentation, the ``#:`` comment above it, ending in its unit.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from mvm.core.config import check_settings, setting, settings_from
from mvm.errors import InputError
from mvm.io.checks import load_toml
from mvm.net.backbone import ARCHITECTURES
from mvm.net.data import AugmentConfig
from mvm.net.losses import DEPTH_LOSSES
from mvm.net.model import ModelSpec


@dataclass(frozen=True)
class DataSource:
    """One data set of the mixture (a ``[[data.train]]`` or ``[data.val]`` table)."""

    #: COCO keypoints file (with or without ``keypoint_depths``). [path]
    annotations: str
    #: Directory of the images; None: the annotation file's directory. [path]
    images: str | None = None
    #: Relative sampling weight of the set while it is active. [1]
    weight: float = setting(1.0, ge=0)
    #: The step from which the set is sampled (0: from the start). [steps]
    start_step: int = setting(0, ge=0)
    #: Read ``keypoint_depths`` when present; false: the set is trained as 2D-only. [bool]
    use_depth: bool = True
    #: Drop the images without any person annotation (as PifPaf does with COCO). [bool]
    people_only: bool = True
    #: Smallest random rescale of this set's crops (PifPaf on COCO: about 0.5; 1: none, the
    #: paper's MVM recipe). [1]
    scale_min: float = setting(1.0, gt=0)
    #: Largest random rescale of this set's crops (PifPaf on COCO: about 2). [1]
    scale_max: float = setting(1.0, gt=0)

    def __post_init__(self):
        check_settings(self)

    def implied_problems(self) -> list[tuple[str, str]]:
        if self.scale_min > self.scale_max:
            return [("scale_min", f"must be <= scale_max ({self.scale_max:g}), got {self.scale_min:g}")]
        return []


@dataclass(frozen=True)
class TrainConfig:
    """Every setting of a training run (read from TOML: :func:`load_config`)."""

    # --- data ------------------------------------------------------------------------------
    #: The data sets of the mixture (``[[data.train]]`` tables, see :class:`DataSource`). [tables]
    train: tuple[DataSource, ...] = ()
    #: An optional validation set (a ``[data.val]`` table). [table]
    val: DataSource | None = None
    # --- network (see :class:`mvm.net.model.ModelSpec`) -------------------------------------
    #: The backbone, a ResNet by depth. [name]
    backbone: str = setting("resnet50", choices=tuple(ARCHITECTURES))
    #: Pixels per cell of the output fields. [px]
    stride: int = setting(16, choices=(8, 16))
    #: Channels of the backbone's stem (64 for ImageNet weights; smaller for CPU demos). [channels]
    width: int = setting(64, ge=4)
    #: 2: the backbone runs at twice the stride and the heads upsample their fields. [1]
    upsample: int = setting(1, choices=(1, 2))
    #: torchvision ImageNet state dict of the backbone ('' for none). [path]
    pretrained: str = ""
    #: Start from this checkpoint's (EMA) weights ('' for none). [path]
    init_checkpoint: str = ""
    # --- augmentation (see :class:`mvm.net.data.AugmentConfig`) -----------------------------
    #: Side of the square network input the crops are resized to (at least one cell of the
    #: coarsest stride). [px]
    input_size: int = setting(385, ge=16)
    #: Smallest side of the random square crop, as a fraction of the image's short edge. [0-1]
    crop_min: float = setting(0.95, gt=0, le=1)
    #: Largest side of the random square crop, as a fraction of the image's short edge. [0-1]
    crop_max: float = setting(1.0, gt=0, le=1)
    #: Probability of a horizontal flip (left and right joints swapped). [0-1]
    flip: float = setting(0.5, ge=0, le=1)
    #: Data-loading processes (0: in the training process). [processes]
    workers: int = setting(0, ge=0)
    # --- optimizer -------------------------------------------------------------------------
    #: "sgd" (the paper's) or "adamw" (faster from scratch on small networks). [name]
    optimizer: str = setting("sgd", choices=("sgd", "adamw"))
    #: Learning rate. [1]
    lr: float = setting(1e-3, gt=0)
    #: Steps of linear warm-up of the learning rate from lr / 100. [steps]
    lr_warmup: int = setting(0, ge=0)
    #: "none" (constant) or "cosine" (to lr / 100 at the end of the run: ``steps`` or
    #: ``max_seconds``, whichever comes first). [name]
    lr_decay: str = setting("none", choices=("none", "cosine"))
    #: Stop training after this long even before ``steps`` (0: no limit). [s]
    max_seconds: float = setting(0.0, ge=0)
    #: Rescale the gradient to at most this norm before each step (0: never). [1]
    clip_grad_norm: float = setting(0.0, ge=0)
    #: Momentum of SGD (unused by AdamW). [1]
    momentum: float = setting(0.95, ge=0, lt=1)
    #: Images per step (per process under ``torchrun``). [images]
    batch_size: int = setting(8, ge=1)
    #: Weight decay of the optimizer. [1]
    weight_decay: float = setting(0.0, ge=0)
    #: Weight of the current parameters in the moving average of the weights, per step. [1]
    ema_decay: float = setting(1e-3, gt=0, le=1)
    #: Optimization steps of the run. [steps]
    steps: int = setting(100000, ge=1)
    # --- loss ------------------------------------------------------------------------------
    #: λ1, the weight of the PIF loss. [1]
    lambda_pif: float = setting(1.0, ge=0)
    #: λ2, the weight of the PAF loss. [1]
    lambda_paf: float = setting(1.0, ge=0)
    #: λ3, the weight of the PDF (depth) loss. [1]
    lambda_pdf: float = setting(1.0, ge=0)
    #: Weight of background cells in the confidence losses (lower: the few positive cells
    #: count more; faster to learn, confidences less calibrated). [1]
    background_weight: float = setting(1.0, ge=0)
    #: Unit of the log-depth residuals in the depth loss (1: the paper's variance as written;
    #: about 0.1, the spread of relative log depths, balances it against the other terms). [log depth]
    depth_log_scale: float = setting(1.0, gt=0)
    #: "image" (the paper's L_PDF: one variance over all labelled locations of an image, which
    #: keeps who stands in front of whom) or "person" (one variance per person). [name]
    depth_loss: str = setting("image", choices=DEPTH_LOSSES)
    # --- output ----------------------------------------------------------------------------
    #: Where checkpoints and metrics.jsonl go (a directory, created when missing). [path]
    out_dir: str = "runs/mvm-net"
    #: Steps between checkpoints. [steps]
    checkpoint_every: int = setting(5000, ge=1)
    #: Steps between validations of ``val`` (0: at the end only); a validation also writes a
    #: checkpoint. [steps]
    val_every: int = setting(0, ge=0)
    #: Checkpoints kept besides the best (0: keep all; a ResNet-152 checkpoint is about
    #: 700 MB). [checkpoints]
    keep_last: int = setting(0, ge=0)
    #: Validation metric whose best checkpoint is never pruned ('' for none; e.g. 'AP';
    #: ``depth_error*`` metrics count lower as better). [name]
    keep_best: str = ""
    #: "fp32" or "bf16" (autocast of the forward pass; the loss stays in fp32). [name]
    precision: str = setting("fp32", choices=("fp32", "bf16"))
    #: Steps between log lines. [steps]
    log_every: int = setting(50, ge=1)
    #: "auto" (a GPU when there is one), "cpu" or "cuda". [name]
    device: str = setting("auto", choices=("auto", "cpu", "cuda"))
    #: Random seed of the weights, the sampling and the augmentation. [1]
    seed: int = setting(0, ge=0, le=2**63 - 1)
    #: CPU threads of torch during the run (0: torch's default; 1 is much faster on a CPU
    #: shared with other processes). [threads]
    threads: int = setting(0, ge=0)

    def __post_init__(self):
        check_settings(self)

    def implied_problems(self) -> list[tuple[str, str]]:
        """The data sets are :class:`DataSource` tables, the crop range is a range and
        ``out_dir`` can be a directory."""
        problems = []
        if not isinstance(self.train, tuple) or not all(isinstance(s, DataSource) for s in self.train):
            problems.append(("train", "expected a list of tables with 'annotations' ([[data.train]])"))
        if self.val is not None and not isinstance(self.val, DataSource):
            problems.append(("val", f"expected a table with 'annotations' ([data.val]), got {self.val!r}"))
        if self.crop_min > self.crop_max:
            problems.append(("crop_min", f"must be <= crop_max ({self.crop_max:g}), got {self.crop_min:g}"))
        if Path(self.out_dir).is_file():
            problems.append(("out_dir", f"{self.out_dir} is a file, expected a directory"))
        return problems

    @property
    def model_spec(self) -> ModelSpec:
        return ModelSpec(self.backbone, self.stride, self.width, self.upsample)

    @property
    def augment(self) -> AugmentConfig:
        return AugmentConfig(self.input_size, self.crop_min, self.crop_max, self.flip)

    def replace(self, **changes) -> TrainConfig:
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


#: The TOML tables whose keys are settings (``[model]``, ``[data]``, …); they are flattened.
SECTIONS = ("model", "data", "optim", "loss", "output")


def config_from_dict(doc: dict, source: str = "config", overrides: dict | None = None) -> TrainConfig:
    """A :class:`TrainConfig` from a TOML document read from ``source`` (its :data:`SECTIONS`
    flattened) and ``overrides`` (flat keys, from ``--set``, named so in errors)."""
    values: dict = {}
    for key, value in doc.items():
        if key in SECTIONS and isinstance(value, dict):
            values.update(value)
        else:
            values[key] = value
    values.update(overrides or {})
    sources = {key: "--set" for key in overrides or {}}
    if "train" in values:
        where = sources.get("train", source)
        if not isinstance(values["train"], (list, tuple)):
            raise InputError(where, "train", "expected a list of tables ([[data.train]])")
        values["train"] = tuple(_data_source(t, where, f"train[{i}]") for i, t in enumerate(values["train"]))
    if isinstance(values.get("val"), dict):
        values["val"] = _data_source(values["val"], sources.get("val", source), "val")
    return settings_from(TrainConfig, values, source, sources=sources)


def _data_source(table, source: str, name: str) -> DataSource:
    if isinstance(table, DataSource):
        return table
    if not isinstance(table, dict) or "annotations" not in table:
        raise InputError(source, name, "expected a table with 'annotations'")
    try:
        return settings_from(DataSource, table, source)
    except InputError as e:
        raise InputError(e.path, f"{name}.{e.field}", e.problem) from None


def load_config(path: str | Path, overrides: dict | None = None) -> TrainConfig:
    """Read a TOML training configuration; ``overrides`` (flat keys, from ``--set``) replace
    its values. A bad setting raises an InputError naming the file or ``--set``. The settings may
    also sit in a ``[train]`` table, as ``mvm config`` prints them."""
    path = Path(path)
    doc = load_toml(path)
    if isinstance(doc.get("train"), dict):
        doc = doc["train"]
    return config_from_dict(doc, str(path), overrides)
