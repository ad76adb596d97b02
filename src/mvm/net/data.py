"""COCO keypoint data sets (2D-only or with per-keypoint depth) and the training augmentations.

An annotation may carry ``keypoint_depths`` (17 relative depths, 0 where missing) and
``has_3d`` (17 flags), as written by :func:`mvm.net.supervision.export_supervision` and read by
:mod:`mvm.io.coco_dataset`. Without them the PDF gets no target (the paper's 2D-only pretraining).

Augmentations (Section 5 of the paper): a square crop whose side is ``crop_min``–``crop_max``
of the image's short edge at a random position, a horizontal flip that swaps left and right
keypoints (``FLIP_PERMUTATION``), and a resize to ``input_size``; optionally a random rescale
(``scale_min``–``scale_max``, as PifPaf trains on COCO: the crop side is divided by it, so
people appear larger or smaller, with zero padding where the crop leaves the image).

COCO as PifPaf treats it: crowd regions (``iscrowd``) and people annotated without keypoints
are not background but *ignored* (their boxes carry no confidence target); with
``people_only`` images without any person annotation are dropped (COCO 2017 train: 64,115
images). An MVM export marks the people it did not reconstruct the same way.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mvm.core.config import check_settings, setting
from mvm.core.keypoints import FLIP_PERMUTATION
from mvm.io.coco_dataset import read_coco_dataset
from mvm.io.images import read_image
from mvm.net.encoder import EncoderConfig, encode
from mvm.net.model import IMAGE_MEAN, IMAGE_STD

LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class AugmentConfig:
    """The random augmentation of training images."""

    #: Side of the square network input. [px]
    input_size: int = setting(385, ge=16, le=8192)
    #: Smallest side of the random square crop, as a fraction of the short edge. [fraction]
    crop_min: float = setting(0.95, gt=0, le=1)
    #: Largest side of the random square crop, as a fraction of the short edge. [fraction]
    crop_max: float = setting(1.0, gt=0, le=1)
    #: Probability of a horizontal flip. [0-1]
    flip: float = setting(0.5, ge=0, le=1)
    #: Smallest random rescale, drawn log-uniformly (1, 1: none; > 1 magnifies the people). [1]
    scale_min: float = setting(1.0, gt=0)
    #: Largest random rescale (see ``scale_min``). [1]
    scale_max: float = setting(1.0, gt=0)

    def __post_init__(self):
        check_settings(self)

    def implied_problems(self) -> list[tuple[str, str]]:
        """A range's low end may not exceed its high end."""
        return [(low, f"must be <= {high} ({getattr(self, high):g}), got {getattr(self, low):g}")
                for low, high in (("crop_min", "crop_max"), ("scale_min", "scale_max"))
                if getattr(self, low) > getattr(self, high)]


@dataclass(frozen=True)
class Annotations:
    """A COCO keypoints file. ``keypoints[i]: (N_i, 17, 3)``, ``depths[i]: (N_i, 17)`` (NaN: none),
    ``ignore[i]: (M_i, 4)`` boxes ``x0, y0, x1, y1`` of crowds and people without keypoints."""

    image_ids: np.ndarray
    paths: tuple[Path, ...]
    keypoints: tuple[np.ndarray, ...]
    depths: tuple[np.ndarray, ...]
    document: dict
    ignore: tuple[np.ndarray, ...] = ()

    def box_of(self, i: int) -> np.ndarray:
        return self.ignore[i] if self.ignore else np.zeros((0, 4))


def read_annotations(path: str | Path, images_dir: str | Path | None = None, min_keypoints: int = 1,
                     people_only: bool = False) -> Annotations:
    """Read a COCO keypoints file (:func:`mvm.io.coco_dataset.read_coco_dataset`: every
    problem one line naming the file and the field); images are found under ``images_dir``
    (default: the file's directory).

    Persons with fewer than ``min_keypoints`` visible joints, and crowds, become ignore boxes
    (from their ``bbox``); ``people_only`` drops the images without any person annotation.
    """
    path = Path(path)
    data = read_coco_dataset(path)
    people = data.people
    root = Path(images_dir) if images_dir is not None else path.parent
    I = len(people.file_names)
    labelled = ~data.crowd & ((people.keypoints[:, :, 2] > 0).sum(1) >= min_keypoints)
    ignored = ~labelled & np.isfinite(data.boxes).all(1)
    keep = np.unique(people.ann_image) if people_only else np.arange(I)
    if people_only:
        LOG.info("%s: %d of %d images show people", path, len(keep), I)

    def per_image(values: np.ndarray, rows: np.ndarray) -> list[np.ndarray]:
        """``values[rows]`` grouped by image, in file order, for the images ``keep``."""
        image = people.ann_image[rows]
        order = np.argsort(image, kind="stable")
        parts = np.split(values[rows][order], np.cumsum(np.bincount(image, minlength=I))[:-1])
        return [parts[i] for i in keep]

    return Annotations(
        image_ids=people.image_ids[keep],
        paths=tuple(root / people.file_names[i].replace("\\", "/") for i in keep),
        keypoints=tuple(per_image(people.keypoints, labelled)),
        depths=tuple(per_image(data.depths, labelled)),
        document=data.document,
        ignore=tuple(per_image(data.boxes, ignored)),
    )


def load_image(path: Path) -> np.ndarray:
    """-> ``(H, W, 3)`` uint8 RGB; a missing or unreadable file raises an InputError."""
    return read_image(path)[:, :, ::-1]


def random_crop_flip(image: np.ndarray, keypoints: np.ndarray, depths: np.ndarray,
                     config: AugmentConfig, rng: np.random.Generator,
                     boxes: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """Square crop of 95–100 % of the short edge (divided by a random rescale) at a random
    place, resize, random flip.

    ``image: (H, W, 3)``, ``keypoints: (N, 17, 3)``, ``depths: (N, 17)`` -> the same for the
    ``input_size²`` result; keypoints that leave the crop get ``v = 0`` and no depth. With
    ``boxes: (M, 4)`` (``x0, y0, x1, y1``), their transformed boxes are returned fourth.
    """
    import cv2

    H, W = image.shape[:2]
    side = rng.uniform(config.crop_min, config.crop_max) * min(H, W)
    if config.scale_min != 1.0 or config.scale_max != 1.0:
        side /= float(np.exp(rng.uniform(np.log(config.scale_min), np.log(config.scale_max))))
    side = max(1, int(round(side)))
    x0 = int(rng.integers(min(0, W - side), max(0, W - side) + 1))
    y0 = int(rng.integers(min(0, H - side), max(0, H - side) + 1))
    S = config.input_size
    if 0 <= x0 and 0 <= y0 and x0 + side <= W and y0 + side <= H:
        crop = cv2.resize(np.ascontiguousarray(image[y0:y0 + side, x0:x0 + side]), (S, S),
                          interpolation=cv2.INTER_AREA if side > S else cv2.INTER_LINEAR)
    else:                                                     # the crop leaves the image: zero padding
        k = S / side
        A = np.array([[k, 0, (0.5 - x0) * k - 0.5], [0, k, (0.5 - y0) * k - 0.5]])
        crop = cv2.warpAffine(np.ascontiguousarray(image), A, (S, S), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    kp = keypoints.copy()
    kp[..., 0] = (kp[..., 0] - x0 + 0.5) * S / side - 0.5
    kp[..., 1] = (kp[..., 1] - y0 + 0.5) * S / side - 0.5
    b = None if boxes is None else (np.asarray(boxes, dtype=float).reshape(-1, 4) - [x0, y0, x0, y0]) * S / side
    d = depths.copy()
    if rng.uniform() < config.flip:
        crop = np.ascontiguousarray(crop[:, ::-1])
        kp[..., 0] = S - 1 - kp[..., 0]
        kp, d = kp[:, FLIP_PERMUTATION], d[:, FLIP_PERMUTATION]
        if b is not None:
            b = np.stack([S - 1 - b[:, 2], b[:, 1], S - 1 - b[:, 0], b[:, 3]], -1)
    out = (kp[..., 0] < 0) | (kp[..., 0] > S - 1) | (kp[..., 1] < 0) | (kp[..., 1] > S - 1)
    kp[out, 2] = 0
    kp[kp[..., 2] <= 0, :2] = 0
    d[kp[..., 2] <= 0] = np.nan
    return (crop, kp, d) if b is None else (crop, kp, d, b)


def letterbox(image: np.ndarray, size: int, stride: int) -> tuple[np.ndarray, float]:
    """Resize the long edge to ``size`` and pad right/bottom to a multiple of ``stride``.

    ``image: (H, W, 3)`` -> ``(H', W', 3)`` and the scale (pixels of the result per original pixel).
    """
    import cv2

    H, W = image.shape[:2]
    scale = size / max(H, W)
    w, h = max(1, int(round(W * scale))), max(1, int(round(H * scale)))
    resized = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    Hp, Wp = -(-h // stride) * stride, -(-w // stride) * stride
    out = np.zeros((Hp, Wp, 3), dtype=image.dtype)
    out[:h, :w] = resized
    return out, scale


def to_tensor(image: np.ndarray) -> torch.Tensor:
    """``(H, W, 3)`` uint8 RGB -> ``(3, H, W)`` float, ImageNet-normalized."""
    x = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float() / 255.0
    mean = torch.tensor(IMAGE_MEAN).view(3, 1, 1)
    std = torch.tensor(IMAGE_STD).view(3, 1, 1)
    return (x - mean) / std


class KeypointDataset(torch.utils.data.Dataset):
    """Training samples: augmented image and field targets.

    ``dataset[i]`` -> ``{"image": (3, S, S), "pif": (17, 5, h, w), "paf": (C, 7, h, w),
    "pdf": (17, 2, h, w), "pdf_group": (17, h, w)}`` with ``h = w = ceil(S / stride)``.
    The random augmentation of item ``i`` depends on ``(seed, epoch, i)`` only.
    """

    def __init__(self, annotations: Annotations, stride: int, augment: AugmentConfig = AugmentConfig(),
                 encoder: EncoderConfig = EncoderConfig(), seed: int = 0, use_depth: bool = True):
        self.ann, self.stride, self.augment, self.encoder = annotations, stride, augment, encoder
        self.seed, self.epoch, self.use_depth = seed, 0, use_depth

    def __len__(self) -> int:
        return len(self.ann.paths)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return self.sample(i, self.epoch)

    def sample(self, i: int, draw: int) -> dict[str, torch.Tensor]:
        """Item ``i`` under the augmentation numbered ``draw``."""
        rng = np.random.default_rng([self.seed, draw, i])
        image = load_image(self.ann.paths[i])
        depths = self.ann.depths[i] if self.use_depth else np.full(self.ann.depths[i].shape, np.nan)
        crop, kp, d, boxes = random_crop_flip(image, self.ann.keypoints[i], depths, self.augment, rng,
                                              self.ann.box_of(i))
        S = self.augment.input_size
        targets = encode(kp, (S, S), self.stride, d, self.encoder, ignore_boxes=boxes)
        out = {k: torch.from_numpy(v) for k, v in targets.items()}
        out["image"] = to_tensor(crop)
        return out


def collate(batch: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    return {k: torch.stack([b[k] for b in batch]) for k in batch[0]}
