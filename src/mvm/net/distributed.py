"""Where training runs: the device, and the process group of a ``torchrun`` launch."""
from __future__ import annotations

import os
from dataclasses import dataclass

import torch

from mvm.errors import InputError


def select_device(name: str, index: int = 0) -> torch.device:
    """'auto' (a GPU when there is one), 'cpu' or 'cuda' (an InputError without a GPU)."""
    if name not in ("auto", "cpu", "cuda"):
        raise InputError(None, "device", f"expected auto, cpu or cuda, got {name!r}")
    if name == "cuda" and not torch.cuda.is_available():
        raise InputError(None, "device", "cuda requested but no GPU is available")
    if name == "cpu" or not torch.cuda.is_available():
        return torch.device("cpu")
    return torch.device("cuda", index)


@dataclass
class Distributed:
    """The process group of a ``torchrun`` launch (world size 1 without one)."""

    rank: int = 0
    world: int = 1
    local_rank: int = 0

    @classmethod
    def from_environment(cls, device: str) -> Distributed:
        """Join the process group ``torchrun`` describes (``WORLD_SIZE``, ``RANK``,
        ``LOCAL_RANK``): NCCL on GPUs, gloo on CPUs."""
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
        """Whether this process writes (rank 0)."""
        return self.rank == 0

    def wait_for_all(self) -> None:
        """Wait until every process got here (a run's end: none tears its connections down while
        another still writes, which aborted gloo's processes now and then)."""
        if self.world > 1 and torch.distributed.is_initialized():
            torch.distributed.barrier()

    def close(self) -> None:
        if self.world > 1 and torch.distributed.is_initialized():
            torch.distributed.destroy_process_group()


def unwrap(model: torch.nn.Module) -> torch.nn.Module:
    """The network inside a ``DistributedDataParallel`` wrapper (or ``model`` itself)."""
    return model.module if isinstance(model, torch.nn.parallel.DistributedDataParallel) else model
