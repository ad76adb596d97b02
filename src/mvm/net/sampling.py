"""The mixture of data sets a run trains on: which image of which set each sample draws.

A data set joins the mixture at its ``start_step`` (COCO pretraining first, then the Mannequin
data) and is then drawn by its weight. The stream of samples is deterministic given the seed,
so a resumed run continues it, and the processes of a ``torchrun`` launch share it out.
"""
from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterator

import numpy as np
import torch

from mvm.errors import InputError
from mvm.net.data import KeypointDataset, collate, read_annotations
from mvm.net.encoder import EncoderConfig
from mvm.net.train_config import TrainConfig

LOG = logging.getLogger(__name__)


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


def build_datasets(cfg: TrainConfig) -> MixtureDataset:
    """The data sets of ``cfg.train``, read and with their augmentation; an InputError when
    there is none or one has no image with a person."""
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


def training_loader(cfg: TrainConfig, step: int, rank: int = 0, world: int = 1) -> torch.utils.data.DataLoader:
    """The batches of process ``rank`` of ``world`` from ``step`` on (``batch_size`` images
    each; the global batch is ``batch_size · world``)."""
    data = build_datasets(cfg)
    sampler = MixtureSampler([len(d) for d in data.datasets], [s.weight for s in cfg.train],
                             [s.start_step for s in cfg.train], cfg.batch_size * world, cfg.seed,
                             start=step * cfg.batch_size * world, rank=rank, world=world)
    return torch.utils.data.DataLoader(data, batch_size=cfg.batch_size, sampler=sampler, collate_fn=collate,
                                       num_workers=cfg.workers, persistent_workers=cfg.workers > 0,
                                       pin_memory=torch.cuda.is_available() and cfg.device != "cpu")
